"""Dumped piles: tetrapods poured into a ring fence that is removed once they rest (sonardet.sim.layout,
sonardet.sim.scene.settle_dumps), and the config checks of the dump keys."""

import copy
import json

import numpy as np
import pytest

from sonardet.config import ConfigError, validate_config
from sonardet.geometry import quat_to_matrix
from sonardet.objects import build_object, object_info
from sonardet.sim.layout import plan_layout
from sonardet.sim.scene import class_geometry, simulate_scene

DUMP = {
    "seed": 3,
    "objects": {"sections": 32},
    "sensor": {"n_beams": 256},
    "scenes": {"n_scenes": 2, "extent_m": [18, 18], "n_objects": [10, 10],
               "class_mix": {"tetrapod_s": 1.0, "reef_ring": 0.0, "reef_cone": 0.0, "tetrapod_b": 0.0},
               "scatter_fraction": [0.0, 0.0], "n_rocks": [2, 2], "dump_fraction": 1.0, "dump_n": [10, 10],
               "physics": {"max_time_s": 6.0}},
    "split": {"n_test": 1, "n_dev": 1},
}


@pytest.fixture(scope="module")
def dumped():
    with pytest.warns(Warning):  # the zero class weights are warned about
        cfg = validate_config(DUMP)
    objs = {c: object_info(build_object(c, cfg["objects"]), 2400.0) for c in cfg["classes"]}
    return cfg, objs, simulate_scene("s0000", cfg, objs)


def test_a_dumped_pile_is_one_group_in_layers(dumped):
    _, _, scene = dumped
    objs = scene.meta["objects"]
    assert not scene.meta["removed"], scene.meta["removed"]
    assert len(objs) == 10 and {o["arrangement"] for o in objs} == {"pile"}
    assert len({o["group"] for o in objs}) == 1
    assert all(o["dumped"] for o in objs)  # marked in the scene JSON (benchmarks/piles.py 'dumped')
    layers = [o["layer"] for o in objs]
    assert min(layers) == 0 and max(layers) >= 1, layers  # some rest on others after the slump
    assert "dump_physics_s" in scene.meta["timings_s"]
    # the fence is gone: every non-seabed sounding belongs to an object or a rock, none floats in the air
    centres = np.array([o["box"][:2] for o in objs])
    spread = np.hypot(*(centres - centres.mean(0)).T).max()
    assert spread < 6.0, spread  # still one heap, not scattered over the scene


def test_a_realism_variant_reuses_the_poured_and_settled_piles(dumped):
    """A realism variant of a dumped-pile scene from the settled layout (its poured and slumped
    poses, layers and removals) is the scene settling again would give, byte for byte."""
    cfg, objs, scene = dumped
    variant = copy.deepcopy(cfg)
    variant["sensor"]["realism"] = {"range_quantum_m": 0.0029}
    with pytest.warns(Warning):
        variant = validate_config(variant)
    reused = simulate_scene("s0000", variant, objs, settled=json.loads(json.dumps(scene.settled)))
    assert reused.meta["timings_s"]["physics_reused"] == 1.0 and "dump_physics_s" not in reused.meta["timings_s"]
    assert [o["layer"] for o in reused.meta["objects"]] == [o["layer"] for o in scene.meta["objects"]]
    again = simulate_scene("s0000", variant, objs)
    for k in ("xyz", "label"):
        assert getattr(again, k).tobytes() == getattr(reused, k).tobytes(), k
    assert again.meta["objects"] == reused.meta["objects"] and again.meta["rocks"] == reused.meta["rocks"]


def test_dumped_spawns_start_apart_and_tumbled(dumped):
    cfg, objs, _ = dumped
    verts, radius, height = class_geometry(objs)
    spawns, unplaced = plan_layout({"tetrapod_s": 10}, radius, height, verts, (0, 18, 0, 18), cfg["scenes"],
                                   lambda x, y: 0.0, np.random.default_rng(1))
    assert not unplaced and len(spawns) == 10
    fence = spawns[0].fence
    assert fence is not None and all(s.fence is fence for s in spawns)
    # bounding spheres disjoint at spawn, every element inside the fence, orientations not all upright
    v = verts["tetrapod_s"]
    cen, rad = [], []
    for s in spawns:
        w = v @ quat_to_matrix(s.q).T + s.t
        mid = 0.5 * (w.min(0) + w.max(0))
        cen.append(mid)
        rad.append(np.linalg.norm(w - mid, axis=1).max())
        assert np.hypot(mid[0] - fence.x, mid[1] - fence.y) <= fence.radius_m + 1e-9
        assert w[:, 2].min() > 0.0  # above the (flat) seabed
    cen, rad = np.array(cen), np.array(rad)
    d = np.linalg.norm(cen[:, None] - cen[None], axis=2) + np.eye(10) * 1e9
    assert np.all(d >= rad[:, None] + rad[None] - 1e-9)
    tilts = [np.degrees(np.arccos(np.clip(quat_to_matrix(s.q)[2, 2], -1, 1))) for s in spawns]
    assert max(tilts) > 20


def test_no_dump_keeps_the_rows():
    cfg = validate_config({"scenes": {"dump_fraction": 0.0}})
    assert cfg["scenes"]["dump_n"] == [15, 20]
    with pytest.raises(ConfigError, match="scenes.dump_n"):
        validate_config({"scenes": {"dump_n": [20, 15]}})
    with pytest.raises(ConfigError, match="dump_fraction"):
        validate_config({"scenes": {"dump_fraction": 1.5}})


def test_default_scenes_dump_full_size_piles_and_keep_the_total():
    """The default distribution has dumped piles of dump_n (15-20) tetrapod_s in about dump_fraction of
    the scenes; a scene that drew fewer takes the shortfall from the other classes, its total kept."""
    from sonardet.sim.layout import draw_dumps
    from sonardet.sim.scene import class_counts

    cfg = validate_config({})
    sc = cfg["scenes"]
    assert sc["dump_fraction"] == 0.5 and sc["dump_n"] == [15, 20]
    rng = np.random.default_rng(0)
    sizes, short = [], 0
    for _ in range(200):
        counts = class_counts(sc, cfg["classes"], rng)
        before = dict(counts)
        dumps = draw_dumps(counts, sc, rng)
        assert sum(counts.values()) == sum(before.values())
        assert set(dumps) <= {"tetrapod_s"}
        if dumps:
            sizes.append(dumps["tetrapod_s"])
            short += before["tetrapod_s"] < dumps["tetrapod_s"]
            assert counts["tetrapod_s"] >= dumps["tetrapod_s"]
            assert all(counts[c] <= before[c] for c in counts if c != "tetrapod_s")
    assert 70 <= len(sizes) <= 130 and min(sizes) >= 15 and max(sizes) <= 20
    assert short > 0  # the borrowing did happen
    # a small scene keeps half of its other objects; no draw at all with dump_fraction 0
    counts = {"reef_ring": 2, "reef_cone": 2, "tetrapod_b": 0, "tetrapod_s": 1}
    assert draw_dumps(counts, {**sc, "dump_fraction": 1.0}, np.random.default_rng(1)) == {"tetrapod_s": 3}
    assert counts == {"reef_ring": 1, "reef_cone": 1, "tetrapod_b": 0, "tetrapod_s": 3}
    rng = np.random.default_rng(2)
    state = rng.bit_generator.state
    assert draw_dumps({"tetrapod_s": 20}, {**sc, "dump_fraction": 0.0}, rng) == {}
    assert rng.bit_generator.state == state


def test_the_pile_interval_brackets_the_pile_ap_and_ignores_other_objects():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    from piles import arrangement_ap, arrangement_interval

    ev = {"headline_m": 0.5, "dist_thresholds_m": [0.5, 1.0], "min_recall": 0.1, "min_precision": 0.1}

    def obj(x, dumped, score=None):
        o = {"cls": "tetrapod_s", "box": [x, 0.0, -11.0, 1.4, 1.4, 1.4, 0.0], "dumped": dumped}
        return o | ({"score": score} if score is not None else {})

    gt = {f"d{k}": [obj(0, True), obj(3, True), obj(9, False)] for k in range(6)}
    # Every pile member found; in half the scenes the one outside the pile is missed (don't care).
    dets = {s: [obj(0.1, True, 0.9), obj(3.1, True, 0.8)] + ([obj(9, False, 0.7)] if k % 2 else [])
            for k, s in enumerate(gt)}
    assert arrangement_ap(gt, dets, ["tetrapod_s"], "dumped", ev)["tetrapod_s"] == (pytest.approx(1.0), 12)
    assert arrangement_interval(gt, dets, "tetrapod_s", "dumped", ev) == (pytest.approx(1.0), pytest.approx(1.0))
    # Half the scenes lose one member: the AP falls and the interval has width and holds it.
    for s in list(gt)[:3]:
        dets[s] = dets[s][:1]
    ap = arrangement_ap(gt, dets, ["tetrapod_s"], "dumped", ev)["tetrapod_s"][0]
    lo, hi = arrangement_interval(gt, dets, "tetrapod_s", "dumped", ev)
    assert ap < 1.0 and lo <= ap <= hi and hi - lo > 0.05


def test_every_raised_leg_of_a_pile_seeds_a_tumbled_hypothesis():
    from types import SimpleNamespace

    from sonardet.detect.model_based.ours import _residual_seeds
    from sonardet.detect.model_based.params import resolve_params

    # One cluster whose sounding density is one broad mound (a pile seen from above), 4 m x 1.5 m,
    # with three raised legs.
    rng = np.random.default_rng(0)
    xy = rng.normal([2.0, 0.75], [1.2, 0.5], size=(20000, 2))
    legs = np.array([[0.6, 0.75], [2.0, 0.75], [3.4, 0.75]])
    d = np.min(np.hypot(*(xy[:, None, :] - legs[None]).transpose(2, 0, 1)), axis=1)
    hab = 0.4 + np.clip(1.0 - d, 0.0, None)  # 1.4 m at each leg's tip, 0.4 m between
    st = SimpleNamespace(pts=np.c_[xy, hab - 11.0], hab=hab)
    p = resolve_params({}, "ours")
    seeds = _residual_seeds(st, np.arange(len(xy)), p)
    for leg in legs:
        assert min(np.hypot(*(s - leg)) for s, _ in seeds) < 0.2
    assert any(tip for _, tip in seeds) and not all(tip for _, tip in seeds)
    assert len(seeds) <= p["residual_max_seeds_n"] + 1  # the cap, plus the centroid
    plain = _residual_seeds(st, np.arange(len(xy)), resolve_params({"residual_height_seeds": False}, "ours"))
    assert not any(tip for _, tip in plain)
    assert sum(min(np.hypot(*(s - leg)) for s, _ in plain) < 0.2 for leg in legs) < 3


@pytest.mark.parametrize("tip", [True, False])
def test_a_tumbled_start_puts_the_raised_tip_under_a_height_seed(tip):
    """At a height seed (tip) each pose starts with its highest point under the seed at the crop's top;
    at a density seed it starts centred on the seed, on the seabed and lifted to the crop's top."""
    from types import SimpleNamespace

    from sonardet.detect.model_based.models import rot_x
    from sonardet.detect.model_based.ours import _tumbled_starts
    from sonardet.detect.model_based.params import resolve_params

    # A model: a leg from the origin to (0.6, 0, 1.2) (a leaning member's raised leg) and a foot.
    verts = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 1.2], [-0.6, 0.3, 0.0], [0.0, -0.6, 0.0]])
    m = SimpleNamespace(vertices=verts)
    ground = SimpleNamespace(z_at=lambda x, y: -11.0)
    pts = np.array([[5.0, 5.0, -9.3], [5.2, 5.0, -10.5]])  # the crop's top 1.7 m above the seabed
    st = SimpleNamespace(ground=ground, pts=pts, hab=pts[:, 2] + 11.0)
    p = resolve_params({"tumbled_vertex_stride_n": 1}, "ours")
    seed = np.array([5.0, 5.0])
    starts = _tumbled_starts(st, m, [np.eye(3), rot_x(0.2)], seed, np.arange(2), p, tip)
    tips = []
    for R0, t0 in starts:
        v = verts @ R0.T + t0
        tips.append(v[np.argmax(v[:, 2])])
    under = [np.allclose(q, [5.0, 5.0, -9.3]) for q in tips]
    assert sum(under) == (2 if tip else 0)
    assert len(starts) == (2 if tip else 4)  # tip; or seabed and lifted (1.7 m crop over a 1.2 m pose)
    off = _tumbled_starts(st, m, [np.eye(3)], seed, np.arange(2), p | {"tumbled_tip_starts": False}, True)
    assert len(off) == 2  # the option off: a height seed starts like any other
