"""Tests of sonardet.sim.physics: MuJoCo settling on the seabed heightfield and on other bodies."""

import mujoco
import numpy as np
import pytest
import trimesh

from sonardet.geometry import quat_to_matrix
from sonardet.sim.physics import (
    REASON_BAD_START,
    REASON_BELOW_TERRAIN,
    REASON_NOT_SETTLED,
    REASON_OUT_OF_BOUNDS,
    RigidBody,
    build_model,
    place_above,
    settle,
)
from sonardet.sim.rocks import make_rock
from sonardet.sim.seabed import Heightfield, make_seabed


# ----------------------------------------------------------------------------- helpers
def box_part(lx, ly, lz):
    """Vertices of a box with its base centre at the origin (canonical frame)."""
    return np.asarray(trimesh.creation.box([lx, ly, lz]).vertices) + [0.0, 0.0, lz / 2]


def posed(body, pos, quat):
    """All convex-part vertices of a body at pose (pos, quat), stacked (N, 3)."""
    return np.vstack(body.convex_parts) @ quat_to_matrix(quat).T + pos


def plane_field(slope_deg=0.0, z0=-11.5, extent=8.0, cell=0.1, dip_axis=0):
    """Planar heightfield over [0, extent]^2 dipping along +x (dip_axis 0) or +y (1)."""
    n = int(round(extent / cell)) + 1
    X, Y = np.meshgrid(np.arange(n) * cell, np.arange(n) * cell)
    d = X if dip_axis == 0 else Y
    return Heightfield(0.0, 0.0, cell, z0 - np.tan(np.radians(slope_deg)) * (d - extent / 2))


def rough_field(seed=3, extent=10.0):
    return make_seabed(extent_m=(extent, extent), cell_m=0.1, slope_deg=2.0, slope_azimuth_deg=135.0,
                       amplitude_m=0.2, base_wavelength_m=4.0, roughness_m=0.01, margin_m=0.5,
                       rng=np.random.default_rng(seed))


def tetrapod_parts(height=1.42, sections=16, root_ratio=0.3, taper=0.6):
    """4 tapered cylinders (frustums) at tetrahedral angles, each its own convex part; one leg up."""
    s = np.sqrt(8.0 / 9.0)
    ang = np.deg2rad([0.0, 120.0, 240.0])
    dirs = np.vstack([[0.0, 0.0, 1.0], np.stack([s * np.cos(ang), s * np.sin(ang), np.full(3, -1 / 3)], 1)])
    leg = height / (4.0 / 3.0 + taper * root_ratio * s)
    r0 = root_ratio * leg
    parts = []
    for d in dirs:
        prof = np.array([[0.0, 0.0], [r0, 0.0], [taper * r0, leg], [0.0, leg], [0.0, 0.0]])
        m = trimesh.creation.revolve(prof, sections=sections)
        m.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], d))
        parts.append(np.asarray(m.vertices))
    zmin = min(p[:, 2].min() for p in parts)
    return [p - [0.0, 0.0, zmin] for p in parts], dirs


def ring_parts(r_out=1.34, wall=0.09, height=0.75, n=16):
    """Thick-walled ring (reef ring-like) as n convex annulus sectors, base at z = 0."""
    parts = []
    r_in = r_out - wall
    for k in range(n):
        a = np.linspace(2 * np.pi * k / n, 2 * np.pi * (k + 1) / n, 4)
        ring = np.vstack([np.c_[r_out * np.cos(a), r_out * np.sin(a)], np.c_[r_in * np.cos(a), r_in * np.sin(a)]])
        parts.append(np.vstack([np.c_[ring, np.zeros(len(ring))], np.c_[ring, np.full(len(ring), height)]]))
    return parts


def rot_quat(axis, angle_rad):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.r_[np.cos(angle_rad / 2), np.sin(angle_rad / 2) * axis]


RNG = lambda: np.random.default_rng(0)  # noqa: E731


# ----------------------------------------------------------------------------- model mapping
def test_model_mass_and_mesh_frames_match_the_body():
    hf = plane_field()
    rock = make_rock(0.8, np.random.default_rng(1))
    parts = [np.asarray(rock.vertices) + [0.2, -0.1, 0.0], box_part(0.3, 0.2, 0.1) + [0.5, 0.0, 0.2]]
    q = rot_quat([1, 2, 3], 0.7)
    body = RigidBody("r", parts, 321.0, [4.0, 4.0, -10.0], q)
    model, info = build_model([body], hf)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.body_mass[info["body_ids"][0]] == pytest.approx(321.0, rel=1e-6)
    for k, g in enumerate(info["geom_ids"][0]):
        mid = model.geom_dataid[g]
        mv = model.mesh_vert[model.mesh_vertadr[mid]:model.mesh_vertadr[mid] + model.mesh_vertnum[mid]]
        world = data.geom_xpos[g] + mv.astype(float) @ data.geom_xmat[g].reshape(3, 3).T
        expect = parts[k] @ quat_to_matrix(q).T + body.pos
        d = np.linalg.norm(world[:, None, :] - expect[None, :, :], axis=2).min(1)
        assert d.max() < 1e-5  # every hull vertex is one of the body's posed vertices


def test_hfield_mapping_boxes_rest_on_height_at():
    """A small box dropped at several (x, y) of a sloped, rough seabed rests at height_at(x, y)."""
    hf = rough_field()
    xy = [(1.0, 1.0), (5.0, 5.0), (8.7, 2.3), (2.5, 8.9), (7.33, 7.71), (9.4, 9.4)]
    part = box_part(0.1, 0.1, 0.1)
    bodies = [RigidBody(f"box{i}", [part], 2.5, place_above([part], [1, 0, 0, 0], (x, y), hf, 0.02))
              for i, (x, y) in enumerate(xy)]
    res = settle(bodies, hf, rng=RNG(), max_time_s=3.0)
    assert res.removed == [] and res.all_at_rest
    for k, b in enumerate(bodies):
        pos, q = res.pose(b.name)
        v = posed(b, pos, q)
        # the cube's centre is half its size above the terrain under it (whichever face it rests on),
        # and its lowest corner sits on the terrain
        c = pos + quat_to_matrix(q) @ [0.0, 0.0, 0.05]
        assert c[2] - 0.05 == pytest.approx(float(hf.height_at(c[0], c[1])), abs=0.01)
        low = v[np.argmin(v[:, 2])]
        assert low[2] == pytest.approx(float(hf.height_at(low[0], low[1])), abs=0.01)
        assert np.hypot(*(pos[:2] - xy[k])) < 0.05  # stays put: friction 0.7 on a 2 deg slope


@pytest.mark.parametrize("slope_deg", [0.0, 12.0])
def test_box_rests_on_flat_and_sloped_seabed(slope_deg):
    hf = plane_field(slope_deg)
    q0 = rot_quat([0, 0, 1], 0.3)
    b = RigidBody("box", [box_part(0.6, 0.4, 0.3)], 170.0, place_above([box_part(0.6, 0.4, 0.3)], q0, (4, 4), hf, 0.01),
                  q0)
    res = settle([b], hf, rng=RNG(), max_time_s=4.0)
    assert res.names == ["box"] and res.all_at_rest
    pos, q = res.pose("box")
    v = posed(b, pos, q)
    gap = v[:, 2] - hf.height_at(v[:, 0], v[:, 1])
    assert abs(gap.min()) < 0.02  # lowest vertex on the terrain
    assert np.sort(gap)[3] < 0.02  # a face (4 corners) rests on it, not an edge
    up = quat_to_matrix(q)[:, 2]
    assert np.degrees(np.arccos(up[2])) == pytest.approx(slope_deg, abs=1.5)  # tilted with the seabed
    assert np.hypot(pos[0] - 4.0, pos[1] - 4.0) < 0.3  # friction 0.7 holds it on 12 deg (no sliding away)
    assert 0.0 < res.settle_time_s[0] < 4.0 and res.n_steps > 0


def test_two_boxes_stacked_rest_on_each_other():
    hf = plane_field(2.0)
    lower = RigidBody("lower", [box_part(1.0, 1.0, 0.5)], 1200.0, [4.0, 4.0, float(hf.height_at(4.0, 4.0)) + 0.1])
    upper = RigidBody("upper", [box_part(0.6, 0.6, 0.3)], 260.0, [4.05, 3.95, lower.pos[2] + 0.5 + 0.2],
                      rot_quat([0, 0, 1], 0.5))
    res = settle([lower, upper], hf, rng=RNG(), max_time_s=5.0)
    assert res.removed == [] and res.all_at_rest
    pl, ql = res.pose("lower")
    pu, qu = res.pose("upper")
    top_of_lower = pl + quat_to_matrix(ql) @ [0.0, 0.0, 0.5]
    bottom_of_upper = pu  # canonical origin = base centre
    assert np.linalg.norm(bottom_of_upper - top_of_lower) < 0.2  # on top, near the middle
    n = quat_to_matrix(ql)[:, 2]
    assert abs(np.dot(bottom_of_upper - top_of_lower, n)) < 0.02  # resting on the top face
    assert res.final_penetration_m < 0.02
    assert res.touching == [("lower", "upper")]


def test_body_on_static_rock():
    hf = plane_field()
    rock = RigidBody("rock", [box_part(1.2, 1.2, 0.4)], 1.0, [4.0, 4.0, -11.5 - 0.1], static=True)
    b = RigidBody("box", [box_part(0.4, 0.4, 0.2)], 80.0, [4.0, 4.0, -11.0])
    res = settle([rock, b], hf, rng=RNG(), max_time_s=3.0)
    assert res.names == ["rock", "box"]
    assert np.array_equal(res.pose("rock")[0], rock.pos) and res.settle_time_s[0] == 0.0
    assert res.pose("box")[0][2] == pytest.approx(-11.6 + 0.4, abs=0.02)


# ----------------------------------------------------------------------------- removals
def test_spawned_outside_bounds_or_under_the_seabed_is_removed():
    hf = plane_field()
    part = [box_part(0.3, 0.3, 0.3)]
    bodies = [
        RigidBody("ok", part, 60.0, [4.0, 4.0, -11.3]),
        RigidBody("outside", part, 60.0, [7.5, 4.0, -11.3]),
        RigidBody("buried", part, 60.0, [2.0, 2.0, -12.5]),
    ]
    res = settle(bodies, hf, rng=RNG(), max_time_s=2.0, bounds_xy=(1.0, 7.0, 1.0, 7.0))
    assert res.names == ["ok"]
    assert {(r.name, r.reason) for r in res.removed} == {("outside", REASON_BAD_START), ("buried", REASON_BAD_START)}
    with pytest.raises(KeyError, match="bad_start"):
        res.pose("outside")


def test_body_sliding_out_of_bounds_is_removed():
    hf = plane_field(40.0, extent=8.0, cell=0.2)  # tan 40 = 0.84 > friction 0.7: slides
    b = RigidBody("slider", [box_part(0.5, 0.5, 0.2)], 100.0, [3.0, 4.0, float(hf.height_at(3.0, 4.0)) + 0.2])
    keep = RigidBody("still", [box_part(0.5, 0.5, 0.2)], 100.0, [3.0, 4.0, 0.0], static=True)
    res = settle([b, keep], hf, rng=RNG(), max_time_s=4.0, bounds_xy=(1.0, 6.0, 1.0, 7.0))
    assert res.removed_names == ["slider"] and res.removed[0].reason == REASON_OUT_OF_BOUNDS
    assert res.removed[0].pos[0] > 6.0 and res.names == ["still"]


def test_body_falling_through_the_seabed_is_removed():
    # a body spawned with its top just under the surface (allowed start) but below a 1 mm thin
    # hfield base never touches the seabed and falls through
    hf = plane_field()
    falls = RigidBody("falls", [box_part(0.3, 0.3, 0.3)], 50.0, [4.0, 4.0, -11.5 - 0.32])
    ok = RigidBody("ok", [box_part(0.3, 0.3, 0.3)], 50.0, [2.0, 2.0, -11.4])
    res = settle([falls, ok], hf, rng=RNG(), max_time_s=2.0, below_terrain_m=0.2, base_m=0.001)
    assert res.names == ["ok"]
    assert [(r.name, r.reason) for r in res.removed] == [("falls", REASON_BELOW_TERRAIN)]
    assert res.removed[0].time_s < 0.5


def test_body_still_moving_at_time_limit_is_removed():
    hf = plane_field()
    b = RigidBody("late", [box_part(0.3, 0.3, 0.3)], 50.0, [4.0, 4.0, -9.0])
    res = settle([b], hf, rng=RNG(), max_time_s=0.2)
    assert res.names == [] and not res.all_at_rest
    assert res.removed[0].reason == REASON_NOT_SETTLED and res.removed[0].time_s == pytest.approx(0.2, abs=0.01)


# ----------------------------------------------------------------------------- behaviour
def test_determinism_same_inputs_same_poses():
    hf = rough_field(seed=5, extent=8.0)
    parts, _ = tetrapod_parts(1.0, sections=12)
    bodies = [RigidBody("t0", parts, 700.0, place_above(parts, rot_quat([1, 1, 0], 1.0), (3.0, 3.0), hf, 0.1),
                        rot_quat([1, 1, 0], 1.0)),
              RigidBody("b0", [box_part(0.5, 0.4, 0.3)], 150.0,
                        place_above([box_part(0.5, 0.4, 0.3)], rot_quat([0, 1, 0], 0.4), (5.5, 5.0), hf, 0.1),
                        rot_quat([0, 1, 0], 0.4))]
    r1 = settle(bodies, hf, rng=np.random.default_rng(42), max_time_s=4.0)
    r2 = settle(bodies, hf, rng=np.random.default_rng(42), max_time_s=4.0)
    assert r1.names == r2.names == ["t0", "b0"]
    assert r1.pos.tobytes() == r2.pos.tobytes() and r1.quat.tobytes() == r2.quat.tobytes()
    assert r1.n_steps == r2.n_steps


def test_tetrapod_rests_on_three_legs():
    hf = rough_field(seed=7, extent=8.0)
    parts, dirs = tetrapod_parts(1.42)
    for k, (axis, angle) in enumerate([([1, 0, 0], 2.0), ([0.3, 1, 0.2], 1.2), ([1, -1, 0.5], 2.8)]):
        q = rot_quat(axis, angle)
        b = RigidBody("tetra", parts, 2000.0, place_above(parts, q, (4.0, 4.0), hf, 0.1), q)
        res = settle([b], hf, rng=np.random.default_rng(k), max_time_s=6.0)
        assert res.names == ["tetra"] and res.all_at_rest
        pos, qf = res.pose("tetra")
        world_dirs = dirs @ quat_to_matrix(qf).T
        up = np.degrees(np.arccos(np.clip(world_dirs[:, 2], -1, 1)))
        assert up.min() < 20.0  # the fourth leg points (roughly) up
        # the three other legs' tips touch the seabed
        tips = []
        for j in np.argsort(up)[1:]:
            v = parts[j] @ quat_to_matrix(qf).T + pos
            tips.append((v[:, 2] - hf.height_at(v[:, 0], v[:, 1])).min())
        assert np.all(np.abs(tips) < 0.03)


def test_rings_stacked_two_layers_rest_on_each_other():
    hf = plane_field(1.0)
    parts = ring_parts()
    z0 = float(hf.height_at(4.0, 4.0))
    lower = RigidBody("ring0", parts, 1300.0, [4.0, 4.0, z0 + 0.1])
    upper = RigidBody("ring1", parts, 1300.0, [4.02, 3.98, z0 + 0.1 + 0.75 + 0.15], rot_quat([0, 0, 1], 0.2))
    res = settle([lower, upper], hf, rng=RNG(), max_time_s=5.0)
    assert res.removed == [] and res.all_at_rest
    pl, ql = res.pose("ring0")
    pu, qu = res.pose("ring1")
    assert pu[2] - pl[2] == pytest.approx(0.75, abs=0.02)  # upper base on the lower rim
    assert np.hypot(*(pu[:2] - pl[:2])) < 0.1
    assert res.final_penetration_m < 0.02
    assert res.touching == [("ring0", "ring1")]


def test_tetrapod_pile_three_layers_without_deep_interpenetration():
    """Hard case (piled objects): 4 upright small tetrapods, 2 dropped on them, 1 on top of those."""
    hf = plane_field(1.0, extent=10.0)
    parts, _ = tetrapod_parts(1.0, sections=12)
    centre = np.array([5.0, 5.0])
    rng = np.random.default_rng(0)
    bodies = []
    for j, (dx, dy) in enumerate([(-1, -1), (1, -1), (-1, 1), (1, 1)]):
        q = rot_quat([0, 0, 1], rng.uniform(0, 2 * np.pi))
        pos = place_above(parts, q, centre + 0.675 * np.array([dx, dy]), hf, 0.02)
        bodies.append(RigidBody(f"l0_{j}", parts, 700.0, pos, q))
    top = max(posed(b, b.pos, b.quat)[:, 2].max() for b in bodies)
    for layer, n in [(1, 2), (2, 1)]:
        layer_top = -np.inf
        for j in range(n):
            q = rot_quat(rng.normal(size=3), rng.uniform(0, np.pi))
            xy = centre + (0.4 * np.array([np.cos(np.pi * j + layer), np.sin(np.pi * j + layer)]) if n > 1 else 0.0)
            v = np.vstack(parts) @ quat_to_matrix(q).T
            pos = np.r_[xy, top - v[:, 2].min() + 0.05]  # spawned above the layer below
            bodies.append(RigidBody(f"l{layer}_{j}", parts, 700.0, pos, q))
            layer_top = max(layer_top, pos[2] + v[:, 2].max())
        top = layer_top
    res = settle(bodies, hf, rng=RNG(), max_time_s=8.0)
    assert res.initial_penetration_m == 0.0
    assert res.removed == [] and res.all_at_rest
    assert res.final_penetration_m < 0.02  # resting on each other, not inside each other
    upper = [b.name for b in bodies if not b.name.startswith("l0")]
    leaning = [n for n in upper if any(n in pair for pair in res.touching)]
    assert len(leaning) >= 2 and len(res.touching) >= 3
    for b in bodies:  # nobody pushed into the seabed
        v = posed(b, *res.pose(b.name))
        assert (v[:, 2] - hf.height_at(v[:, 0], v[:, 1])).min() > -0.02


def test_sleep_and_no_sleep_agree_on_a_simple_scene():
    hf = plane_field(3.0)
    bodies = [RigidBody(f"b{i}", [box_part(0.4, 0.3, 0.2)], 60.0, [1.5 + 1.5 * i, 4.0, -11.0]) for i in range(4)]
    r1 = settle(bodies, hf, rng=RNG(), sleep=True)
    r0 = settle(bodies, hf, rng=RNG(), sleep=False)
    assert r1.names == r0.names and r1.all_at_rest and r0.all_at_rest
    assert np.abs(r1.pos - r0.pos).max() < 0.005


def test_place_above_clears_the_seabed():
    hf = rough_field()
    parts, _ = tetrapod_parts(2.0)
    q = rot_quat([1, 0.5, 0], 1.1)
    pos = place_above(parts, q, (5.0, 5.0), hf, clearance_m=0.1)
    v = np.vstack(parts) @ quat_to_matrix(q).T + pos
    gap = v[:, 2] - hf.height_at(v[:, 0], v[:, 1])
    assert gap.min() >= 0.1 - 1e-9 and gap.min() < 0.5
    with pytest.raises(ValueError):
        place_above(parts, q, (0.1, 0.1), hf)


def test_empty_and_static_only_scenes():
    hf = plane_field()
    r = settle([], hf, rng=RNG())
    assert r.names == [] and r.n_steps == 0 and r.all_at_rest and r.pos.shape == (0, 3)
    s = RigidBody("s", [box_part(1, 1, 1)], 1.0, [2.0, 2.0, -11.6], static=True)
    r = settle([s], hf, rng=RNG())
    assert r.names == ["s"] and r.n_steps == 0 and np.array_equal(r.pos[0], s.pos)


def test_rigid_body_and_settle_validation():
    hf = plane_field()
    with pytest.raises(ValueError):
        RigidBody("x", [], 1.0, [0, 0, 0])
    with pytest.raises(ValueError):
        RigidBody("x", [np.zeros((3, 3))], 1.0, [0, 0, 0])
    with pytest.raises(ValueError):
        RigidBody("x", [box_part(1, 1, 1)], 0.0, [0, 0, 0])
    b = RigidBody("x", [box_part(1, 1, 1)], 1.0, [4, 4, -11])
    with pytest.raises(ValueError, match="unique"):
        settle([b, b], hf, rng=RNG())
    with pytest.raises(ValueError):
        settle([b], hf, rng=RNG(), bounds_xy=(5, 4, 0, 8))
    # quaternions are normalised with w >= 0
    assert np.allclose(RigidBody("q", [box_part(1, 1, 1)], 1.0, [0, 0, 0], [-2, 0, 0, 0]).quat, [1, 0, 0, 0])
