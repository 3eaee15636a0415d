"""Sensor realism profile: each effect does what it says, all-off changes no byte, seeds reproduce."""

import json
from dataclasses import fields

import numpy as np
import open3d as o3d
import pytest
import trimesh

from sonardet.config import ConfigError, read_schema, validate_config
from sonardet.seeds import config_hash
from sonardet.objects import build_object
from sonardet.objects import object_info
from sonardet.sim.mbes import RaycastTarget, SensorConfig, Trajectory, beam_angles, scan, straight_line
from sonardet.sim.effects import RealismConfig
from sonardet.sim.effects.burial import burial_depths
from sonardet.sim.effects.footprint import subray_bundle
from sonardet.sim.scene import simulate_scene

NOISELESS = dict(range_sigma_m=0.0, dropout_prob=0.0, grazing_dropout_prob=0.0)
DEPTH = 11.5


def rect(x0, x1, y0, y1, z):
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def merge(parts):
    vs, fs, n = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + n)
        n += len(v)
    return np.vstack(vs), np.vstack(fs)


SEABED = rect(-60, 60, -60, 60, -DEPTH)
FLAT = RaycastTarget([SEABED], [-2])


def sensor(realism=None, **kw):
    return SensorConfig(**{"n_beams": 256, **NOISELESS, **kw},
                        realism=None if realism is None else RealismConfig(**realism))


def run(target, s, length=2.0, seed=0, y=0.0):
    traj = straight_line([-length / 2, y], [length / 2, y], 0.0, s, DEPTH)
    return scan(target, traj, s, np.random.default_rng(seed)), traj


def per_beam_mean(out, n_beams):
    return np.array([out.xyz[out.beam == b].mean(0) for b in range(n_beams)])


def sounding_bytes(out):
    return b"".join(a.tobytes() for a in (out.xyz, out.ping, out.beam, out.line, out.mesh)) + \
        np.array([out.n_rays, out.n_dropped]).tobytes()


def clutter_target():
    box = trimesh.creation.box([2, 1.5, 1.0])
    box.apply_translation([1, 3, -11.0])
    ball = trimesh.creation.icosphere(3, 0.7)
    ball.apply_translation([-2, -4, -11.2])
    return RaycastTarget([SEABED, (box.vertices, box.faces), (ball.vertices, ball.faces)], [-2, 0, 1])


# --- all off -------------------------------------------------------------------------------------

def test_all_off_profile_gives_identical_bytes():
    target = clutter_target()
    th = np.linspace(0, 1.0, 30)
    curved = Trajectory(np.c_[5 * np.cos(th), 5 * np.sin(th), np.zeros(30)], th + np.pi / 2, np.full(30, 3))
    base = dict(n_beams=200, spacing="equidistant", range_sigma_m=0.05, dropout_prob=0.1, grazing_dropout_prob=0.5)
    for traj, kw in ((straight_line([-6, 0], [6, 0], 0.0, SensorConfig(**base), DEPTH), {}),
                     (curved, dict(beams=np.arange(20, 90), chunk_rays=3000, ping_offset=5))):
        plain = scan(target, traj, SensorConfig(**base), np.random.default_rng(4), **kw)
        for off in (RealismConfig(), RealismConfig.from_config({}), RealismConfig.from_config(None)):
            again = scan(target, traj, SensorConfig(**base, realism=off), np.random.default_rng(4), **kw)
            assert sounding_bytes(again) == sounding_bytes(plain)
        from_cfg = SensorConfig.from_dict({**base, "realism": {}})
        assert sounding_bytes(scan(target, traj, from_cfg, np.random.default_rng(4), **kw)) == sounding_bytes(plain)
    # Templates record the sensor settings: an all-off profile records the same ones as none.
    assert SensorConfig(realism=RealismConfig()).to_dict() == SensorConfig().to_dict()
    assert SensorConfig(realism=RealismConfig(range_quantum_m=0.01)).to_dict()["realism"]["range_quantum_m"] == 0.01


def test_effects_keep_the_sensors_own_noise_realisation():
    # The realism draws come from a spawned child generator: the sensor's dropouts stay the same.
    s0 = sensor(dropout_prob=0.2)
    s1 = sensor(dict(line_offset_sigma_m=0.1), dropout_prob=0.2)
    a, _ = run(FLAT, s0, seed=9)
    b, _ = run(FLAT, s1, seed=9)
    assert np.array_equal(a.beam, b.beam) and np.array_equal(a.ping, b.ping)
    assert np.allclose(b.xyz[:, 2] - a.xyz[:, 2], b.xyz[0, 2] - a.xyz[0, 2])


# --- attitude --------------------------------------------------------------------------------------

def test_roll_bias_tilts_the_swath_by_y_tan_roll():
    base, _ = run(FLAT, sensor())
    tilted, _ = run(FLAT, sensor(dict(roll_bias_deg=0.5)))
    b0, b1 = per_beam_mean(base, 256), per_beam_mean(tilted, 256)
    outer = np.abs(beam_angles(sensor())) > np.deg2rad(60)
    dz = b1[outer, 2] - b0[outer, 2]
    # Beam 0 is port (+y for a line along +x); positive roll (starboard down) raises the starboard side.
    expected = -b0[outer, 1] * np.tan(np.deg2rad(0.5))
    assert np.all(np.abs(dz - expected) < 0.10 * np.abs(expected)), (dz, expected)
    assert 0.19 < np.abs(dz).max() < 0.24  # about 24.7 m * tan(0.5 deg) = 0.215 m at the 65 deg beams
    assert np.abs(b1[128, 2] - b0[128, 2]) < 1e-3


def test_heave_is_an_error_unless_compensated():
    rz = dict(heave_amplitude_m=0.1, heave_period_s=1.0, roll_amplitude_deg=2.0, roll_period_s=1.3)
    raw, _ = run(FLAT, sensor(rz), length=6.0)
    comp, _ = run(FLAT, sensor({**rz, "motion_compensated": True}), length=6.0)
    nadir = raw.beam == 128
    assert 0.09 < np.abs(raw.xyz[nadir, 2] + DEPTH).max() < 0.13
    # Compensated: the soundings lie on the seabed, but the rolling fan moves where they land.
    assert np.abs(comp.xyz[:, 2] + DEPTH).max() < 1e-3
    edge = comp.xyz[comp.beam == 0, 1]
    assert np.ptp(edge) > 1.0


# --- sound speed -----------------------------------------------------------------------------------

@pytest.mark.parametrize("error_mps", [5.0, -5.0])
def test_surface_sound_speed_error_gives_a_smile_or_frown_as_snell_says(error_mps):
    s = sensor(dict(surface_sound_speed_error_mps=error_mps))
    out, _ = run(FLAT, s)
    a = beam_angles(s)
    rise = per_beam_mean(out, 256)[:, 2] + DEPTH
    a_true = np.arcsin(np.sin(a) * 1500.0 / (1500.0 + error_mps))
    expected = DEPTH * (1 - np.cos(a) / np.cos(a_true))
    assert np.allclose(rise, expected, rtol=0.01, atol=1e-4)
    # Smile (outer beams up) when the assumed speed is too high, frown when too low; grows with angle.
    assert np.sign(rise[0]) == np.sign(error_mps) and abs(rise[0]) > 0.15
    half = np.abs(rise[128:])
    assert np.all(np.diff(half) > -1e-5)


def test_svp_bias_grows_with_angle_as_k_depth_sec_minus_one():
    s = sensor(dict(svp_bias_coeff=0.0073))
    out, _ = run(FLAT, s)
    a = beam_angles(s)
    rise = per_beam_mean(out, 256)[:, 2] + DEPTH
    assert np.allclose(rise, 0.0073 * DEPTH * (1 / np.cos(a) - 1), rtol=1e-3, atol=1e-5)
    assert abs(rise[-1] / DEPTH - 0.01) < 0.0005  # 1 % of the depth at 65 deg


# --- footprint ------------------------------------------------------------------------------------

FOOT = dict(footprint_n_across=7, footprint_n_along=3, beamwidth_across_deg=2.0, beamwidth_along_deg=2.0)


def test_footprint_bundle_weights():
    da, dl, w = subray_bundle(RealismConfig(**FOOT))
    assert len(w) == 21 and np.isclose(w.sum(), 1.0)
    assert np.isclose(np.rad2deg(da.max()), 1.0) and np.isclose(np.rad2deg(dl.min()), -1.0)
    assert w.argmax() == 10 and np.isclose(w[0] / w[10], 0.25)  # 1/2 across x 1/2 along at the corner


def test_footprint_amplitude_detection_widens_a_step_edge():
    # A 1 m step whose edge runs along the track 2 m to starboard (y = -2).
    step = trimesh.creation.box([40, 8, 1.0])
    step.apply_translation([0, -6, -11.0])
    target = RaycastTarget([SEABED, (step.vertices, step.faces)])

    def edge_width(out):
        p = out.xyz[(out.xyz[:, 1] < -1) & (out.xyz[:, 1] > -3)]
        mid = p[(p[:, 2] > -11.4) & (p[:, 2] < -10.6)]  # between 10 % and 90 % of the step
        return np.ptp(mid[:, 1]) if len(mid) else 0.0

    point, _ = run(target, sensor(n_beams=512))
    amp, _ = run(target, sensor(FOOT, n_beams=512))
    phase, _ = run(target, sensor({**FOOT, "detection": "phase"}, n_beams=512))
    assert amp.n_rays == 21 * point.n_rays
    assert edge_width(point) < 0.01  # only the wall, at y = -2
    # 2 deg at about 11 m: a footprint of about 0.38 m; beams straddling the edge get blended ranges.
    assert 0.10 < edge_width(amp) < 0.40
    assert edge_width(phase) < 0.01


def test_footprint_hides_a_hole_smaller_than_the_footprint():
    # A plate 1 m above the seabed with a 0.1 m square hole under the track (footprint about 0.37 m).
    h = 0.05
    plate = merge([rect(-1, -h, -1, 1, -10.5), rect(h, 1, -1, 1, -10.5), rect(-h, h, -1, -h, -10.5),
                   rect(-h, h, h, 1, -10.5)])
    target = RaycastTarget([SEABED, plate])
    foot = dict(footprint_n_across=5, footprint_n_along=5, beamwidth_across_deg=2.0, beamwidth_along_deg=2.0)

    def depth_below_plate(rz):
        out, _ = run(target, sensor(rz, speed_mps=0.5), length=0.6)
        p = out.xyz[(np.abs(out.xyz[:, 0]) < 0.1) & (np.abs(out.xyz[:, 1]) < 0.1)]
        assert len(p) > 10
        return -10.5 - p[:, 2].min()

    assert depth_below_plate(None) > 0.95  # single rays see the seabed through the hole
    amplitude = depth_below_plate(foot)
    assert 0.05 < amplitude < 0.5  # the weighted mean fills the hole partly
    assert depth_below_plate({**foot, "detection": "phase"}) < 0.01
    assert depth_below_plate({**foot, "detection": "first"}) < 0.01


# --- quantisation, outliers, dropouts ---------------------------------------------------------------

def test_range_quantisation_gives_multiples_of_the_step():
    step = 0.0029
    plain, traj = run(FLAT, sensor(range_sigma_m=0.01))
    quant, _ = run(FLAT, sensor(dict(range_quantum_m=step), range_sigma_m=0.01))
    for out, is_multiple in ((plain, False), (quant, True)):
        r = np.linalg.norm(out.xyz - traj.position[out.ping], axis=1) / step
        assert np.allclose(r, np.round(r), atol=1e-6) == is_multiple
    assert np.abs(quant.xyz - plain.xyz).max() < step


def test_outliers_share_and_outer_concentration():
    s = sensor(dict(outlier_prob=0.02, outlier_magnitude_m=1.0))
    out, _ = run(FLAT, s, length=20.0)
    spike = np.abs(out.xyz[:, 2] + DEPTH) > 0.02  # every spike moves by >= 0.1 m * cos(65 deg)
    assert len(out.xyz) > 40000
    assert abs(spike.mean() - 0.02) < 0.15 * 0.02
    outer = np.abs(beam_angles(s))[out.beam] > np.deg2rad(50)
    assert spike[outer].mean() > 3 * spike[~outer].mean()
    assert np.abs(out.xyz[:, 2] + DEPTH).max() < 1.0


def test_outer_dropouts_rise_towards_the_swath_edge():
    s = sensor(dict(outer_dropout_prob=0.4, outer_dropout_start_deg=45))
    out, traj = run(FLAT, s, length=20.0)
    n = np.bincount(out.beam, minlength=256) / len(traj)
    a = np.abs(beam_angles(s))
    assert np.all(n[a < np.deg2rad(44)] == 1.0)
    assert abs((1 - n[[0, 255]].mean()) - 0.4) < 0.1
    assert out.n_dropped == len(traj) * 256 - len(out.xyz)


# --- lines -------------------------------------------------------------------------------------------

def test_line_offsets_have_the_configured_sigma():
    sigma = 0.05
    s = sensor(dict(line_offset_sigma_m=sigma), n_beams=16)
    parts = [straight_line([0, 0], [0.1, 0], 0.0, s, DEPTH, line=k) for k in range(600)]
    traj = Trajectory.concatenate(parts)
    out = scan(FLAT, traj, s, np.random.default_rng(1))
    per_line = np.array([out.xyz[out.line == k, 2].mean() + DEPTH for k in range(600)])
    assert np.allclose([np.ptp(out.xyz[out.line == k, 2]) for k in range(3)], 0.0, atol=1e-4)
    assert abs(per_line.std() - sigma) < 0.1 * sigma
    assert abs(np.diff(per_line).std() - sigma * np.sqrt(2)) < 0.1 * sigma * np.sqrt(2)


# --- roughness ---------------------------------------------------------------------------------------

def test_roughness_moves_object_hits_off_the_mesh_by_sigma():
    box = trimesh.creation.box([6, 6, 1.0])
    box.apply_translation([0, 0, -11.0])
    target = RaycastTarget([SEABED, (box.vertices, box.faces)], [-2, 0])
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(np.asarray(box.vertices, np.float32)),
                        o3d.core.Tensor(np.asarray(box.faces, np.uint32)))

    def residuals(rz):
        out, _ = run(target, sensor(rz), length=4.0)
        obj = out.xyz[out.mesh == 0].astype(np.float32)
        d = scene.compute_distance(o3d.core.Tensor(obj)).numpy()
        return np.sqrt(np.mean(d ** 2)), np.abs(out.xyz[out.mesh == -2, 2] + DEPTH).max(), len(obj)

    rms0, sea0, _ = residuals(None)
    rms, sea, n = residuals(dict(object_roughness_sigma_m=0.02))
    assert n > 2000 and rms0 < 1e-4 and sea < 1e-4
    assert abs(rms - 0.02) < 0.15 * 0.02


# --- determinism, config ------------------------------------------------------------------------------

EVERYTHING = dict(footprint_n_across=3, footprint_n_along=2, detection="auto", range_quantum_m=0.0029,
                  roll_bias_deg=0.1, roll_bias_sigma_deg=0.05, pitch_bias_sigma_deg=0.05, roll_amplitude_deg=1.0,
                  pitch_amplitude_deg=0.5, yaw_amplitude_deg=0.5, heave_amplitude_m=0.05,
                  surface_sound_speed_error_mps=2.0, svp_bias_sigma=0.003, outlier_prob=0.01,
                  outer_dropout_prob=0.1, line_offset_sigma_m=0.02, object_roughness_sigma_m=0.01)


def test_deterministic_for_a_seed():
    target = clutter_target()
    s = sensor(EVERYTHING, range_sigma_m=0.01, dropout_prob=0.01, grazing_dropout_prob=0.3)
    a, traj = run(target, s, length=4.0, seed=3)
    b, _ = run(target, s, length=4.0, seed=3)
    c, _ = run(target, s, length=4.0, seed=4)
    assert sounding_bytes(a) == sounding_bytes(b)
    assert sounding_bytes(a) != sounding_bytes(c)
    assert a.n_rays == 6 * 256 * len(traj)


def test_config_keys_documented_validated_and_passed_through():
    schema = read_schema()["properties"]["sensor"]["properties"]["realism"]
    assert "default" not in schema  # leaving the section out keeps the config (and its hash) as it was
    for f in fields(RealismConfig):
        prop = schema["properties"][f.name]
        assert prop.get("default", f.default) == f.default and "description" in prop, f.name
    assert set(schema["properties"]) == {f.name for f in fields(RealismConfig)}

    plain = validate_config({})
    assert "realism" not in plain["sensor"] and "realism" not in plain["scenes"]
    cfg = validate_config({"sensor": {"realism": {"range_quantum_m": 0.0029}}, "scenes": {"realism": {}}})
    assert cfg["sensor"]["realism"]["footprint_n_across"] == 1 and cfg["scenes"]["realism"]["burial_m"] == [0, 0]
    s = SensorConfig.from_dict(cfg["sensor"])
    assert isinstance(s.realism, RealismConfig) and s.realism.range_quantum_m == 0.0029 and s.realism.active
    assert config_hash(plain) != config_hash(cfg)
    with pytest.raises(ConfigError, match="sensor.realism.wobble"):
        validate_config({"sensor": {"realism": {"wobble": 1}}})
    with pytest.raises(ConfigError, match="detection"):
        validate_config({"sensor": {"realism": {"detection": "peak"}}})
    with pytest.raises(ValueError, match="unknown"):
        RealismConfig.from_config({"wobble": 1})
    with pytest.raises(ValueError, match="footprint_n_across"):
        RealismConfig(footprint_n_across=0)


# --- burial (scene) ---------------------------------------------------------------------------------

TINY = {"seed": 3, "classes": ["reef_cone", "tetrapod_s"], "objects": {"sections": 24},
        "sensor": {"n_beams": 128},
        "scenes": {"extent_m": [12, 12], "n_objects": [4, 4], "n_rocks": [1, 1], "cluster_max": 2, "pile_max": 2,
                   "class_mix": {"reef_cone": 1.0, "tetrapod_s": 1.0}, "scatter_fraction": [0.5, 0.5],
                   "physics": {"max_time_s": 2.0}},
        "split": {"n_test": 1}}


@pytest.fixture(scope="module")
def tiny_scenes():
    def make(sensor_extra=None, scenes_extra=None, settled=None, scene_id="s0001"):
        cfg = {**TINY, "sensor": {**TINY["sensor"], **(sensor_extra or {})},
               "scenes": {**TINY["scenes"], **(scenes_extra or {})}}
        cfg = validate_config(cfg)
        return simulate_scene(scene_id, cfg, objects, settled=settled)

    objects = {}
    cfg = validate_config(TINY)
    for c in cfg["classes"]:
        m = build_object(c, cfg["objects"])
        objects[c] = object_info(m, 2400.0)
    plain = make()
    realism = ({"realism": {"range_quantum_m": 0.0029, "footprint_n_across": 3}}, {"realism": {"burial_m": [0.1, 0.3]}})
    return {
        "plain": plain,
        "off": make({"realism": {}}, {"realism": {"burial_m": [0, 0]}}),
        "buried": make(None, {"realism": {"burial_m": [0.1, 0.3]}}),
        "realism": make(*realism),
        # the workflow's realism variants: the plain scene's settled layout, through its JSON file
        "realism_reused": make(*realism, settled=json.loads(json.dumps(plain.settled))),
    }


def test_a_realism_variant_reusing_the_settled_layout_is_the_same_scene(tiny_scenes):
    """The workflow's realism scenes reuse their synthetic scene's settled layout (no second MuJoCo
    run): the soundings and the metadata are those of settling again, byte for byte."""
    a, b = tiny_scenes["realism"], tiny_scenes["realism_reused"]
    for k in ("xyz", "ping", "beam", "line", "label"):
        assert getattr(a, k).tobytes() == getattr(b, k).tobytes(), k
    ta, tb = a.meta.pop("timings_s"), b.meta.pop("timings_s")
    try:
        assert json.dumps(a.meta) == json.dumps(b.meta)
    finally:
        a.meta["timings_s"], b.meta["timings_s"] = ta, tb
    assert "physics_step_s" in ta and "physics_step_s" not in tb and tb["physics_reused"] == 1.0
    assert any("burial_m" in o for o in b.meta["objects"]) and b.settled == a.settled


def test_a_settled_layout_of_another_scene_or_config_is_refused(tiny_scenes):
    settled = tiny_scenes["plain"].settled
    with pytest.raises(ValueError, match="does not belong to scene 's0002'"):
        simulate_scene("s0002", validate_config(TINY), {}, settled=settled)
    other = validate_config({**TINY, "seed": 4})
    with pytest.raises(ValueError, match="seed, classes, objects"):
        simulate_scene("s0001", other, {}, settled=settled)


def test_all_off_scene_has_the_same_points(tiny_scenes):
    plain, off = tiny_scenes["plain"], tiny_scenes["off"]
    for k in ("xyz", "ping", "beam", "line", "label"):
        assert getattr(plain, k).tobytes() == getattr(off, k).tobytes()
    assert plain.meta["objects"] == off.meta["objects"]


def test_burial_lowers_objects_by_the_drawn_depth(tiny_scenes):
    plain, buried = tiny_scenes["plain"], tiny_scenes["buried"]
    assert len(plain.meta["objects"]) == len(buried.meta["objects"]) >= 3
    for a, b in zip(plain.meta["objects"], buried.meta["objects"]):
        d = b["burial_m"]
        assert 0.1 <= d <= 0.3
        assert np.isclose(a["pose"]["t"][2] - b["pose"]["t"][2], d, atol=1e-9)
        assert np.allclose(a["pose"]["t"][:2], b["pose"]["t"][:2]) and np.allclose(a["pose"]["q"], b["pose"]["q"])
        assert np.isclose(a["box"][2] - b["box"][2], d, atol=1e-9)
        # The tops of the objects' soundings sink by the same depth.
        za = plain.xyz[plain.label == a["id"], 2]
        zb = buried.xyz[buried.label == b["id"], 2]
        if len(za) > 100 and len(zb) > 100:
            assert abs((np.percentile(za, 95) - np.percentile(zb, 95)) - d) < 0.05
        assert "burial_m" not in a
    groups = {}
    for o in buried.meta["objects"]:
        if o["group"] >= 0:
            groups.setdefault(o["group"], set()).add(o["burial_m"])
    assert all(len(v) == 1 for v in groups.values())
    assert sum(o["n_points"] for o in buried.meta["objects"]) < sum(o["n_points"] for o in plain.meta["objects"])


def test_burial_depths_by_group():
    d = burial_depths([-1, 0, 0, 2, -1], [0.1, 0.3], np.random.default_rng(0))
    assert d[1] == d[2] and d[0] != d[4] and np.all((d >= 0.1) & (d <= 0.3))
    with pytest.raises(ValueError, match="burial_m"):
        burial_depths([0], [0.3, 0.1], np.random.default_rng(0))
