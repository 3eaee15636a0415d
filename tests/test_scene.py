"""Scene synthesis: determinism, settled objects, annotations, flat-seabed noise, bad configs."""

import json

import numpy as np
import open3d as o3d
import pytest

from sonardet.config import ConfigError, validate_config
from sonardet.geometry import points_in_box, quat_to_matrix
from sonardet.io.scenes import read_scene_points, write_scene
from sonardet.objects import build_object
from sonardet.objects import object_info
from sonardet.sim.dataset import dataset_stats, make_splits, scene_ids
from sonardet.sim.mbes import SensorConfig, beam_angles
from sonardet.sim.scene import simulate_scene

SMALL = {
    "seed": 11,
    "objects": {"sections": 32},
    "sensor": {"n_beams": 256},
    "scenes": {"n_scenes": 3, "extent_m": [18, 18], "n_objects": [11, 12],
               "class_mix": {"tetrapod_s": 0.4, "reef_ring": 0.3, "reef_cone": 0.15, "tetrapod_b": 0.15}, "n_rocks": [2, 3], "cluster_max": 4,
               "pile_max": 5, "big_spacing_m": [5, 6], "scatter_fraction": [0.2, 0.3], "dump_fraction": 0.0,
               "physics": {"max_time_s": 5.0}},
    "split": {"n_test": 1, "n_dev": 1},
}


def _objects(cfg):
    out = {}
    for c in cfg["classes"]:
        m = build_object(c, cfg["objects"])
        out[c] = object_info(m, 2400.0)
    return out


@pytest.fixture(scope="module")
def small():
    cfg = validate_config(SMALL)
    objs = _objects(cfg)
    return cfg, objs, simulate_scene("s0001", cfg, objs)


def test_same_seed_same_bytes(small, tmp_path):
    cfg, objs, scene = small
    again = simulate_scene("s0001", cfg, objs)
    write_scene(scene, tmp_path / "a.npz", tmp_path / "a.json")
    write_scene(again, tmp_path / "b.npz", tmp_path / "b.json")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    ja, jb = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    ja.pop("timings_s"), jb.pop("timings_s")
    assert ja == jb
    other = simulate_scene("s0002", cfg, objs)
    assert len(other.xyz) != len(scene.xyz) or not np.array_equal(other.xyz, scene.xyz)


def test_objects_settled_on_seabed_or_each_other(small):
    cfg, objs, scene = small
    meta = scene.meta
    assert meta["physics"]["all_at_rest"]
    assert len(meta["objects"]) + len(meta["removed"]) + len(meta["unplaced"]) >= cfg["scenes"]["n_objects"][0]
    posed = {}
    for o in meta["objects"]:
        v = np.asarray(objs[o["cls"]].mesh.vertices) @ quat_to_matrix(o["pose"]["q"]).T + o["pose"]["t"]
        posed[o["id"]] = v
    # Ground height under each lowest vertex from the soundings of the seabed (label -1 near it).
    ground = scene.xyz[scene.label == -1]
    flat = np.c_[ground[:, :2], np.zeros(len(ground))]
    tree = o3d.geometry.KDTreeFlann(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(flat)))
    for o in meta["objects"]:
        v = posed[o["id"]]
        low = v[np.argmin(v[:, 2])]
        _, idx, _ = tree.search_knn_vector_3d(np.r_[low[:2], 0.0], 8)
        gz = float(np.median(ground[np.asarray(idx), 2]))
        gap = low[2] - gz
        assert gap > -0.10, f"object {o['id']} ({o['cls']}) sinks {gap:.3f} m into the seabed"
        if gap > 0.10:
            # Not on the seabed: it must rest on another object (a vertex of another within 5 cm).
            others = np.vstack([posed[k] for k in posed if k != o["id"]])
            d = np.min(np.linalg.norm(others - low, axis=1))
            assert d < 0.35, f"object {o['id']} ({o['cls']}) floats {gap:.2f} m above the seabed"


def test_visible_annotations_have_their_points_in_their_box(small):
    _, _, scene = small
    for o in scene.meta["objects"]:
        pts = scene.xyz[scene.label == o["id"]]
        assert len(pts) == o["n_points"]
        if o["visible"]:
            assert len(pts) >= 30
            inside = points_in_box(pts, o["box"], margin_m=0.05)
            assert inside.mean() > 0.99
    assert any(o["visible"] for o in scene.meta["objects"])


def test_scene_contract(small, tmp_path):
    _, _, scene = small
    write_scene(scene, tmp_path / "s.npz", tmp_path / "s.json")
    pts = read_scene_points(tmp_path / "s.npz")
    assert pts["xyz"].dtype == np.float64 and pts["label"].dtype == np.int32
    meta = json.loads((tmp_path / "s.json").read_text())
    assert meta["schema_version"] == 1 and meta["scene"] == "s0001"
    for o in meta["objects"]:
        assert len(o["box"]) == 7 and len(o["pose"]["q"]) == 4 and o["cls"] in SMALL.get("classes", o["cls"])
    assert 50 < meta["stats"]["points_per_m2"] < 600


def test_flat_noiseless_seabed_scene_is_a_plane():
    cfg = validate_config({
        "sensor": {"range_sigma_m": 0.0, "dropout_prob": 0.0, "n_beams": 128},
        "scenes": {"extent_m": [10, 10], "n_objects": [1, 1], "n_rocks": [0, 0],
                   "seabed": {"slope_deg": [0, 0], "amplitude_m": [0, 0], "roughness_m": 0.0}},
    })
    # A bare seabed: the validator refuses scenes without objects for an experiment (nothing to
    # evaluate), so the scene generator gets them after validation.
    cfg["scenes"]["n_objects"] = [0, 0]
    scene = simulate_scene("s0000", cfg, {})
    assert np.ptp(scene.xyz[:, 2]) < 1e-5
    cfg["sensor"]["range_sigma_m"] = 0.01
    scene = simulate_scene("s0000", cfg, {})
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scene.xyz - scene.xyz.mean(0)))
    o3d.utility.random.seed(0)
    (a, b, c, d), _ = pc.segment_plane(0.05, 3, 300)
    res = (scene.xyz - scene.xyz.mean(0)) @ np.array([a, b, c]) + d
    # Range noise along the beam projects on the plane normal with the cosine of the beam angle:
    # expected residual std = sigma * rms(cos(angle)) over the soundings.
    cos = np.cos(beam_angles(SensorConfig.from_dict(cfg["sensor"]))[scene.beam])
    expected = 0.01 * np.sqrt(np.mean(cos**2))
    assert abs(res.std() - expected) < 0.1 * expected


def test_piles_have_upper_layers(small):
    _, _, scene = small
    layers = [o["layer"] for o in scene.meta["objects"] if o["arrangement"] in ("pile", "stack")]
    assert layers and max(layers) >= 1
    assert not any(o["dumped"] for o in scene.meta["objects"])  # dump_fraction 0: rows only


def test_split_is_nested_and_disjoint():
    ids = scene_ids(105)
    sp = make_splits(ids, 20, 5, [25, 50, 100], seed=3)
    assert len(sp["test"]) == 20 and len(sp["train"]) == 80 and len(sp["dev"]) == 5
    assert not set(sp["test"]) & set(sp["train"])
    assert not set(sp["dev"]) & (set(sp["train"]) | set(sp["test"]))
    assert set(sp["train_25"]) <= set(sp["train_50"]) <= set(sp["train_100"]) == set(sp["train"])
    assert len(sp["train_25"]) == 20 and len(sp["train_50"]) == 40
    assert sp == make_splits(ids, 20, 5, [25, 50, 100], seed=3)
    with pytest.raises(ValueError, match="n_test"):
        make_splits(ids[:6], 5, 1, [100], seed=3)


def test_dataset_stats_counts_visible_objects():
    metas = {"s0": {"objects": [{"cls": "reef_ring", "visible": True}, {"cls": "reef_cone", "visible": False}]},
             "s1": {"objects": [{"cls": "reef_ring", "visible": True}, {"cls": "tetrapod_s", "visible": True}]}}
    t = dataset_stats(metas, {"train": ["s0"], "test": ["s1"]}, ["reef_ring", "reef_cone", "tetrapod_s"])
    assert t.set_index("split").loc["all", "objects"] == 3
    assert t.set_index("split").loc["train", "objects_not_visible"] == 1
    assert t.set_index("split").loc["test", "reef_ring_share_pct"] == 50.0


@pytest.mark.parametrize("bad, key", [
    ({"scenes": {"n_objects": [50, 500]}}, "scenes.n_objects"),
    ({"scenes": {"seabed": {"mean_depth_m": 2.0}}}, "scenes.seabed.mean_depth_m"),
    ({"sensor": {"n_beams": 0}}, "sensor.n_beams"),
    ({"split": {"n_test": 100}}, "split.n_test"),
])
def test_impossible_scene_configs_name_the_key(bad, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        validate_config(bad)
