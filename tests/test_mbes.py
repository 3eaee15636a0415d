"""MBES sensor model: beam geometry, ping rate, noise, dropouts, shadows."""

import numpy as np
import open3d as o3d
import pytest
import trimesh

from sonardet.sim.mbes import (
    RaycastTarget,
    SensorConfig,
    Trajectory,
    beam_angles,
    ping_rate_hz,
    scan,
    straight_line,
    survey_lines,
    swath_half_width_m,
)

NOISELESS = dict(range_sigma_m=0.0, dropout_prob=0.0, grazing_dropout_prob=0.0)


def plane(z=-11.5, half=60.0):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_beam_spacing_modes():
    ea = beam_angles(SensorConfig(n_beams=256, spacing="equiangular"))
    ed = beam_angles(SensorConfig(n_beams=256, spacing="equidistant"))
    assert np.allclose(np.diff(ea), np.diff(ea)[0])
    assert np.allclose(np.diff(np.tan(ed)), np.diff(np.tan(ed))[0])
    assert np.isclose(ea[-1], np.deg2rad(65)) and np.isclose(ed[-1], np.deg2rad(65))


def test_ping_rate_limited_by_two_way_travel_time():
    s = SensorConfig(max_ping_rate_hz=50)
    # 11.5 m depth, 65 deg outer beam: R = 27.2 m, PRF = 1500 / 54.4 = 27.6 Hz.
    assert np.isclose(ping_rate_hz(s, 11.5), 1500 / (2 * 11.5 / np.cos(np.deg2rad(65))))
    assert ping_rate_hz(s, 1.0) == 50


@pytest.mark.parametrize("bad", [dict(n_beams=0), dict(swath_deg=181), dict(spacing="random")])
def test_sensor_config_rejects_bad_values(bad):
    with pytest.raises(ValueError):
        SensorConfig(**bad)


def test_flat_noiseless_scan_is_exact():
    s = SensorConfig(n_beams=128, **NOISELESS)
    traj = straight_line([-5, 0], [5, 0], 0.0, s, 11.5)
    out = scan(RaycastTarget([plane()]), traj, s, np.random.default_rng(0))
    assert len(out.xyz) == len(traj) * 128
    assert np.abs(out.xyz[:, 2] + 11.5).max() < 1e-5
    # Across-track positions follow altitude * tan(angle); beam 0 is port (+y for a line along +x).
    first = out.xyz[out.ping == 0]
    assert np.allclose(first[:, 1], -11.5 * np.tan(beam_angles(s)), atol=1e-4)
    assert first[0, 1] > 0


def test_range_noise_matches_sigma():
    s = SensorConfig(n_beams=256, range_sigma_m=0.01, dropout_prob=0, grazing_dropout_prob=0, swath_deg=60)
    traj = straight_line([-10, 0], [10, 0], 0.0, s, 11.5)
    out = scan(RaycastTarget([plane()]), traj, s, np.random.default_rng(1))
    # A RANSAC plane fit, as the source study characterised its sonar: residual std within 10 % of
    # the range sigma projected on the vertical (cos of the beam angle, here up to 30 degrees).
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(out.xyz))
    o3d.utility.random.seed(0)
    model, _ = pc.segment_plane(0.05, 3, 500)
    a, b, c, d = model
    res = (out.xyz @ np.array([a, b, c]) + d) / np.linalg.norm([a, b, c])
    cosang = np.cos(beam_angles(s))[out.beam]
    expected = 0.01 * np.sqrt(np.mean(cosang**2))
    assert abs(res.std() - expected) < 0.1 * expected


def test_dropouts_and_grazing():
    s = SensorConfig(n_beams=200, range_sigma_m=0, dropout_prob=0.1, grazing_dropout_prob=0.0)
    traj = straight_line([-10, 0], [10, 0], 0.0, s, 11.5)
    out = scan(RaycastTarget([plane()]), traj, s, np.random.default_rng(2))
    frac = 1 - len(out.xyz) / out.n_rays
    assert abs(frac - 0.1) < 0.01
    g = SensorConfig(n_beams=200, range_sigma_m=0, dropout_prob=0.0, grazing_dropout_prob=0.8, grazing_start_deg=40)
    out = scan(RaycastTarget([plane()]), traj, g, np.random.default_rng(2))
    inner = np.abs(beam_angles(g)[out.beam]) < np.deg2rad(40)
    counts_inner = inner.sum() / (np.abs(beam_angles(g)) < np.deg2rad(40)).sum()
    counts_outer = (~inner).sum() / (np.abs(beam_angles(g)) >= np.deg2rad(40)).sum()
    assert counts_inner == len(traj)  # no dropouts below the grazing start
    ang = np.abs(beam_angles(g))
    cs = np.cos(np.deg2rad(40))
    p = 0.8 * np.clip((cs - np.cos(ang)) / cs, 0, 1) ** 2  # flat seabed: incidence = beam angle
    expected_outer = (1 - p[ang >= np.deg2rad(40)]).mean() * len(traj)
    assert abs(counts_outer - expected_outer) < 0.01 * len(traj)
    assert expected_outer < 0.97 * len(traj)


def test_deterministic_for_a_seed():
    s = SensorConfig(n_beams=64)
    traj = straight_line([-3, 0], [3, 0], 0.0, s, 11.5)
    a = scan(RaycastTarget([plane()]), traj, s, np.random.default_rng(5))
    b = scan(RaycastTarget([plane()]), traj, s, np.random.default_rng(5))
    assert np.array_equal(a.xyz, b.xyz) and np.array_equal(a.beam, b.beam)


def test_tall_object_casts_shadow_of_expected_length():
    """A 2 m tall block 8 m to starboard: the seabed behind it is unseen for h * tan(angle)."""
    s = SensorConfig(n_beams=1024, **NOISELESS)
    h, depth, x0 = 2.0, 11.5, 8.0
    block = trimesh.creation.box(extents=[4, 0.5, h])
    block.apply_translation([0, -x0, -depth + h / 2])  # starboard of a line along +x is -y
    traj = straight_line([-0.2, 0], [0.2, 0], 0.0, s, depth)
    out = scan(RaycastTarget([plane(-depth), (block.vertices, block.faces)], ids=[0, 1]), traj, s,
               np.random.default_rng(0))
    seabed = out.xyz[(out.mesh == 0) & (out.ping == 0)]
    far_edge = x0 + 0.25
    # Across-track distances to starboard of the seabed returns beyond the block.
    y = -seabed[:, 1]
    behind = np.sort(y[y > far_edge - 0.25])
    first_seen = behind[0]
    top_angle = np.arctan2(far_edge, depth - h)
    expected = depth * np.tan(top_angle) - far_edge  # = h * tan(angle) to the block's far top edge
    assert abs((first_seen - far_edge) - expected) < 0.05
    assert expected > 1.5


def test_survey_lines_cover_extent():
    s = SensorConfig()
    t = survey_lines((0, 40, 0, 40), "xy", 0.0, 11.5, 0.2, s, run_in_m=5)
    assert set(np.unique(t.line)) == set(range(len(np.unique(t.line))))
    half = swath_half_width_m(s, 11.5)
    xs = t.position[np.isclose(np.cos(t.heading_rad), 0, atol=1e-9), 0]
    assert xs.min() - half <= 0 and xs.max() + half >= 40
    with pytest.raises(ValueError):
        survey_lines((0, 40, 0, 40), "z", 0.0, 11.5, 0.2, s)


def test_empty_inputs_give_empty_output():
    s = SensorConfig(n_beams=8)
    out = scan(RaycastTarget([plane()]), Trajectory(np.zeros((0, 3)), [], []), s, np.random.default_rng(0))
    assert out.xyz.shape == (0, 3)
    out = scan(RaycastTarget([plane()]), straight_line([0, 0], [1, 0], 0.0, s, 11.5), s,
               np.random.default_rng(0), beams=np.array([], dtype=int))
    assert len(out.xyz) == 0


def sounding_bytes(out):
    return b"".join(a.tobytes() for a in (out.xyz, out.ping, out.beam, out.line, out.mesh)) + \
        np.array([out.n_rays, out.n_dropped]).tobytes()


def test_slab_size_does_not_change_the_output():
    """scan post-processes each chunk in slabs of pings; the random draws stay per chunk, so any slab
    size gives the same bytes (straight lines take the same-heading ray path, the arc the general one)."""
    block = trimesh.creation.box(extents=[3, 2, 1.5])
    block.apply_translation([0, -4, -10.5])
    target = RaycastTarget([plane(), (block.vertices, block.faces)], ids=[0, 1])
    s = SensorConfig(n_beams=96, range_sigma_m=0.05, dropout_prob=0.05, grazing_dropout_prob=0.5,
                     grazing_start_deg=30)
    th = np.linspace(0, 1.0, 40)
    arc = Trajectory(np.c_[6 * np.cos(th), 6 * np.sin(th) - 6, np.zeros(40)], th + np.pi / 2, np.full(40, 2))
    for traj, kw in ((straight_line([-3, 0], [3, 0], 0.0, s, 11.5), {}),
                     (straight_line([-3, 0], [3, 0], 0.0, s, 11.5), dict(chunk_rays=1000)),
                     (arc, dict(beams=np.arange(10, 80, 3), ping_offset=4, chunk_rays=300))):
        outs = [scan(target, traj, s, np.random.default_rng(7), slab_rays=n, **kw) for n in (1, 250, 1 << 15, 1 << 30)]
        assert len(outs[0].xyz) > 0 and 0 < outs[0].n_dropped
        for out in outs[1:]:
            assert sounding_bytes(out) == sounding_bytes(outs[0])


def test_dropout_draws_decided_per_chunk():
    """Without random dropouts a chunk draws its dropout uniforms only if some beam has a grazing
    dropout probability > 0; the scan may learn that only at a late slab of the chunk, which must not
    change what is drawn."""
    s = SensorConfig(n_beams=64, swath_deg=20, range_sigma_m=0.0, dropout_prob=0.0, grazing_dropout_prob=0.5)
    # Flat seabed only: no dropout probability anywhere, so no draw at all.
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    out = scan(RaycastTarget([plane()]), straight_line([-3, 0], [3, 0], 0.0, s, 11.5), s, rng, slab_rays=64)
    assert rng.bit_generator.state == state and out.n_dropped == 0
    # A wedge under the second half of the line: only its slabs reach grazing incidence.
    wedge = trimesh.creation.box(extents=[2, 4, 1])
    wedge.apply_transform(trimesh.transformations.rotation_matrix(np.deg2rad(75), [1, 0, 0]))
    wedge.apply_translation([2.0, 0, -10.0])
    target = RaycastTarget([plane(), (wedge.vertices, wedge.faces)], ids=[0, 1])
    traj = straight_line([-3, 0], [3, 0], 0.0, s, 11.5)
    for chunk_rays in (1 << 20, 64 * 30):
        outs = [scan(target, traj, s, np.random.default_rng(3), chunk_rays=chunk_rays, slab_rays=n)
                for n in (64, 64 * 7, 1 << 30)]
        assert outs[0].n_dropped > 0 and np.all(outs[0].xyz[outs[0].ping < 40, 0] < 1.0)
        for out in outs[1:]:
            assert sounding_bytes(out) == sounding_bytes(outs[0])


def test_noiseless_output_does_not_depend_on_chunking():
    s = SensorConfig(n_beams=128, **NOISELESS)
    traj = straight_line([-3, 0], [3, 0], 0.0, s, 11.5)
    target = RaycastTarget([plane()])
    ref = scan(target, traj, s, np.random.default_rng(0))
    for chunk_rays in (1, 128 * 5, 1000):
        assert sounding_bytes(scan(target, traj, s, np.random.default_rng(0), chunk_rays=chunk_rays)) == \
            sounding_bytes(ref)
