"""Surveys as one Snakemake job per tile (rules/survey.smk, sonardet.survey).

Unit tests of the library (streaming split, tile index, merge, outputs) and one real `snakemake --cores 2`
run on a synthetic survey larger than a tile. Hard cases named in the tests: UTM offsets (5.5e5, 4.18e6)
kept bit for bit from the file to the outputs, a survey read in many chunks (text .gz, LAS), objects on
the seams and at a seam crossing, an empty tile, a bad line in a later chunk, an overlap smaller than the
objects, a lost tile at the merge, a survey file that does not exist.
"""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, copy_workflow, match_by_centre

from sonardet.config import ConfigError, validate_config
from sonardet.io.annotations import read_detections
from sonardet.io.points import PointCloud, PointCloudError, read_points, write_points
from sonardet.survey import (enabled_surveys, merge_survey_detections, object_footprint_m, open_survey,
                             read_tile_index, read_tile_points, split_survey, survey_settings, tile_ids,
                             write_survey_detections)
from sonardet.survey.tiling import detect_tiled, merge_tile_detections, plan_tiles

UTM = np.array([5.5e5, 4.18e6, 0.0])


# ------------------------------------------------------------------------------------------ helpers
def _blob_survey(extent=(30.0, 20.0), centres=((10.1, 5.0), (5.0, 9.9), (20.05, 9.95), (25.0, 15.0)), seed=0):
    """A noisy seabed plane (-11.5 m) with flat-topped 'objects' (discs of radius 1 m, 1 m high) at
    `centres`, shifted to UTM: points (N,3) float64 in file order (shuffled rows, as a survey's pings
    are not sorted in x)."""
    rng = np.random.default_rng(seed)
    n = int(extent[0] * extent[1] * 40)
    xy = rng.uniform((0, 0), extent, size=(n, 2))
    z = -11.5 + rng.normal(0, 0.01, n)
    for cx, cy in centres:
        inside = np.hypot(xy[:, 0] - cx, xy[:, 1] - cy) < 1.0
        z[inside] += 1.0
    return np.c_[xy, z] + UTM


def _blob_detector(points):
    """A deterministic stand-in for the detector: one detection per connected group of points higher
    than 0.5 m above the seabed, at the group's centroid (a group cut by the tile edge gives a shifted
    centroid, as a partial fit would)."""
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    high = points[points[:, 2] > -11.0]
    if len(high) == 0:
        return []
    graph = cKDTree(high[:, :2]).sparse_distance_matrix(cKDTree(high[:, :2]), 0.4)
    _, labels = connected_components(graph, directed=False)
    out = []
    for k in range(labels.max() + 1):
        c = high[labels == k].mean(0)
        out.append({"cls": "reef_cone", "box": [float(c[0]), float(c[1]), float(c[2]), 2.0, 2.0, 1.0, 0.0],
                    "score": float((labels == k).sum()) / 1000.0, "extras": {"accepted": True}})
    return out


def _recorded_tiled_inputs(xyz, tile_m, overlap_m):
    """The points detect_tiled hands its detector, tile by tile (in plan order)."""
    seen = []
    detect_tiled(xyz, lambda p: seen.append(np.array(p)) or [], tile_m, overlap_m, progress=False)
    return seen


# ------------------------------------------------------------------------------------------ settings
def test_survey_settings_take_the_schema_defaults():
    s = survey_settings("line1", {"path": "a.xyz"})
    assert s == {"name": "line1", "path": "a.xyz", "enabled": True, "crs": None, "z_positive": None, "columns": None,
                 "method": "model_based_ours", "tile_m": 50.0, "overlap_m": 3.0, "chunk_points": 1_000_000,
                 "all_hypotheses": False, "keep_fliers": False}
    # The defaults are those of `sonardet detect` (tile 50 m, overlap 3 m, z direction and columns from the
    # file, fliers left out).
    from sonardet.cli import build_parser

    args = build_parser().parse_args(["detect", "--input", "a", "--out", "b"])
    assert (args.tile_m, args.overlap_m, args.z_positive, args.columns, args.keep_fliers) == (
        s["tile_m"], s["overlap_m"], None, None, s["keep_fliers"])
    with pytest.raises(ValueError, match="surveys.x: needs `path`"):
        survey_settings("x", {})


def test_survey_defaults_are_the_schema_defaults():
    """The survey package keeps its defaults as a constant (it may not import the config layer): they
    must be those the config schema states for a `surveys` entry."""
    from sonardet.config import read_schema
    from sonardet.survey import SURVEY_DEFAULTS, survey_defaults

    props = read_schema()["properties"]["surveys"]["additionalProperties"]["properties"]
    schema = {k: v["default"] for k, v in props.items() if "default" in v}
    assert SURVEY_DEFAULTS == schema and survey_defaults() == schema
    assert all(type(SURVEY_DEFAULTS[k]) is type(v) for k, v in schema.items())
    survey_defaults()["tile_m"] = 1.0  # a copy: the constant is not changed through it
    assert SURVEY_DEFAULTS["tile_m"] == schema["tile_m"]
    # `sonardet detect` tiles like the workflow by default
    from sonardet.cli import build_parser
    from sonardet.survey import DEFAULT_TILE_M

    args = build_parser().parse_args(["detect", "--input", "x.xyz", "--out", "o.json"])
    assert args.tile_m == DEFAULT_TILE_M == SURVEY_DEFAULTS["tile_m"]


def test_default_config_runs_the_real_line():
    from sonardet.config import read_config

    cfg = read_config(REPO / "config" / "config.yaml")
    assert cfg["surveys"]["r2sonic_sfbay"] == {"path": "../shared/data/real/r2sonic_sfbay.xyz.gz",
                                               "crs": "EPSG:32610"}


@pytest.mark.parametrize("bad,key", [
    ({"x y": {"path": "a.xyz"}}, "surveys: 'x y' does not match"),
    ({"a": {"crs": "EPSG:32610"}}, "surveys.a: 'path' is a required property"),
    ({"a": {"path": "a.xyz", "tile_m": 0}}, "surveys.a.tile_m"),
    ({"a": {"path": "a.xyz", "overlap_m": -1}}, "surveys.a.overlap_m"),
    ({"a": {"path": "a.xyz", "method": "detr_100"}}, "surveys.a.method: unknown method 'detr_100'"),
    ({"a": {"path": "a.xyz", "tile": 40}}, "surveys.a.tile: unknown key"),
])
def test_bad_survey_config_names_the_key(bad, key):
    with pytest.raises(ConfigError) as err:
        validate_config({"surveys": bad})
    assert key in str(err.value)


def test_missing_survey_file_is_reported_and_left_out(tmp_path):
    (tmp_path / "here.xyz").write_text("1 2 3\n")
    surveys = {"here": {"path": str(tmp_path / "here.xyz")}, "gone": {"path": str(tmp_path / "gone.xyz")},
               "off": {"path": str(tmp_path / "gone.xyz"), "enabled": False}}
    runs, messages = enabled_surveys(surveys)
    assert list(runs) == ["here"] and runs["here"]["method"] == "model_based_ours"
    assert len(messages) == 1
    assert "surveys.gone.path" in messages[0] and "left out" in messages[0]
    assert "surveys.gone.enabled: false" in messages[0]


def test_object_footprint_is_twice_the_largest_radius():
    square = SimpleNamespace(mesh=SimpleNamespace(vertices=np.array([[1.0, 1.0, 0.0], [-1.0, 0.0, 2.0]])))
    disc = SimpleNamespace(mesh=SimpleNamespace(vertices=np.array([[1.2, 0.0, 0.0], [0.0, -1.2, 0.5]])))
    assert object_footprint_m({"a": square, "b": disc}) == pytest.approx(2 * np.sqrt(2))
    with pytest.raises(ValueError):
        object_footprint_m({})


# ------------------------------------------------------------------------------------------ split
@pytest.mark.parametrize("suffix", [".xyz.gz", ".csv", ".las", ".npz", ".ply"])
def test_tiles_hold_the_points_detect_tiled_gives_each_tile(tmp_path, suffix):
    """Whatever the format, a tile's NPZ holds exactly the points (same float64 values, same order) that
    the one-process path (detect_tiled on read_points) hands the detector for that tile; text and LAS
    are read in chunks of 1000 points."""
    xyz = _blob_survey()
    path = tmp_path / f"survey{suffix}"
    write_points(path, PointCloud(xyz, crs="EPSG:32610" if suffix in (".las", ".npz", ".ply") else None))
    doc = split_survey(path, tmp_path / "tiles", tmp_path / "tile_index.json", survey="s", tile_m=12.0,
                       overlap_m=3.0, crs="EPSG:32610", min_overlap_m=2.0, chunk_points=1000)
    ref = read_points(path).xyz
    seen = _recorded_tiled_inputs(ref, 12.0, 3.0)
    assert doc["n_points"] == len(ref) and doc["streamed"] == (suffix in (".xyz.gz", ".csv", ".las"))
    assert len(doc["tiles"]) == len(seen) == 6
    for t, want in zip(doc["tiles"], seen):
        cloud = read_tile_points(tmp_path / t["file"])
        assert np.array_equal(cloud.xyz, want), t["id"]  # bit for bit, in file order
        assert cloud.xyz.dtype == np.float64 and t["n_points"] == len(want)
        assert cloud.crs == "EPSG:32610" and np.array_equal(cloud.origin, [550000.0, 4180000.0, 0.0])
    # The index: the survey's coordinates and CRS, a whole-metre origin, the plan of detect_tiled.
    assert doc["crs"] == "EPSG:32610" and doc["origin"] == [550000.0, 4180000.0, 0.0]
    lo, hi = ref.min(0), ref.max(0)
    assert doc["bounds"] == [lo[0], lo[1], hi[0], hi[1]]
    index, tiles = read_tile_index(tmp_path / "tile_index.json")
    assert index == doc and tiles == plan_tiles(doc["bounds"], 12.0, 3.0)
    assert not (tmp_path / "tiles" / ".spool").exists()
    assert sorted(p.name for p in (tmp_path / "tiles").iterdir()) == sorted(f"{t.id}.npz" for t in tiles)


def test_index_names_cores_padding_and_ownership(tmp_path):
    path = tmp_path / "s.xyz"
    write_points(path, PointCloud(_blob_survey()))
    doc = split_survey(path, tmp_path / "tiles", tmp_path / "i.json", survey="s", tile_m=12.0, overlap_m=3.0)
    by = {t["id"]: t for t in doc["tiles"]}
    assert (doc["nx"], doc["ny"]) == (3, 2) and doc["crs"] is None
    corner, middle = by["t000_000"], by["t001_001"]
    assert corner["owns"][:2] == [None, None] and corner["owns"][2:] == [corner["core"][2], corner["core"][3]]
    assert middle["owns"] == [middle["core"][0], middle["core"][1], middle["core"][2], None]
    for t in doc["tiles"]:
        assert np.allclose(np.subtract(t["padded"], t["core"]), [-3, -3, 3, 3], rtol=0, atol=1e-9)
        assert t["core"][0] > 5e5 and t["core"][1] > 4e6  # survey coordinates
    assert tile_ids(tmp_path / "i.json") == [t["id"] for t in doc["tiles"]]


def test_chunk_size_does_not_change_the_tiles(tmp_path):
    path = tmp_path / "s.xyz.gz"
    write_points(path, PointCloud(_blob_survey()))
    a = split_survey(path, tmp_path / "a", tmp_path / "a.json", survey="s", tile_m=12.0, chunk_points=1000)
    b = split_survey(path, tmp_path / "b", tmp_path / "b.json", survey="s", tile_m=12.0, chunk_points=10**7)
    def strip(doc):
        return {**doc, "chunk_points": 0, "tiles": [{**t, "file": Path(t["file"]).name} for t in doc["tiles"]]}

    assert strip(a) == strip(b)
    for t in a["tiles"]:
        assert (tmp_path / "a" / f"{t['id']}.npz").read_bytes() == (tmp_path / "b" / f"{t['id']}.npz").read_bytes()


def test_tiles_without_points_get_no_file_and_no_job(tmp_path):
    """An L-shaped survey: the plan's upper right tile holds no point."""
    xyz = _blob_survey()
    xyz = xyz[~((xyz[:, 0] - UTM[0] > 16.0) & (xyz[:, 1] - UTM[1] > 7.0))]
    path = tmp_path / "l.xyz"
    write_points(path, PointCloud(xyz))
    doc = split_survey(path, tmp_path / "tiles", tmp_path / "i.json", survey="s", tile_m=12.0, overlap_m=3.0)
    empty = [t for t in doc["tiles"] if t["file"] is None]
    assert [t["id"] for t in empty] == ["t002_001"] and empty[0]["n_points"] == 0
    assert "t002_001" not in tile_ids(tmp_path / "i.json")
    assert not (tmp_path / "tiles" / "t002_001.npz").exists()


def test_overlap_smaller_than_the_objects_fails_before_reading(tmp_path):
    with pytest.raises(ValueError, match="overlap_m = 2 m is smaller than the largest object footprint"):
        split_survey(tmp_path / "not_read.xyz", tmp_path / "t", tmp_path / "i.json", survey="s", overlap_m=2.0,
                     min_overlap_m=2.73)
    with pytest.raises(FileNotFoundError, match="no such point-cloud file"):
        split_survey(tmp_path / "gone.xyz", tmp_path / "t", tmp_path / "i.json", survey="s")


def test_bad_line_in_a_later_chunk_names_the_line(tmp_path):
    lines = [f"{550000 + i * 0.01:.3f} {4180000 + (i % 97) * 0.1:.3f} -11.5" for i in range(5000)]
    lines[3499] = "550034.990 4180001.000"
    path = tmp_path / "short.xyz.gz"
    path.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    with pytest.raises(PointCloudError, match=r"short\.xyz\.gz line 3500: expected 3 columns, found 2"):
        split_survey(path, tmp_path / "t", tmp_path / "i.json", survey="s", chunk_points=1000)
    lines[3499] = "550034.990 nan -11.5"
    path.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    with pytest.raises(PointCloudError, match=r"line 3500 .*non-finite coordinates"):
        split_survey(path, tmp_path / "t", tmp_path / "i.json", survey="s", chunk_points=1000)
    assert not (tmp_path / "i.json").exists() and not (tmp_path / "t" / ".spool").exists()


def test_crs_of_the_file_and_a_contradicting_one(tmp_path):
    path = tmp_path / "s.las"
    write_points(path, PointCloud(_blob_survey()[:2000], crs="EPSG:32610"))
    assert open_survey(path).crs == "EPSG:32610"
    with pytest.raises(PointCloudError, match="declares CRS"):
        open_survey(path, crs="EPSG:32633")
    text = tmp_path / "s.xyz"
    write_points(text, PointCloud(_blob_survey()[:2000]))
    assert open_survey(text).crs is None and open_survey(text, crs="epsg:32610").crs == "EPSG:32610"


# ------------------------------------------------------------------------------------------ merge
def test_split_detect_merge_equals_detect_tiled(tmp_path):
    """split -> one 'job' per tile on its NPZ -> merge gives what detect_tiled gives, with objects on the
    seams x = 10, 20 m and y = 10 m and one at a seam crossing, each reported once."""
    xyz = _blob_survey()
    path = tmp_path / "s.xyz.gz"
    write_points(path, PointCloud(xyz))
    doc = split_survey(path, tmp_path / "tiles", tmp_path / "i.json", survey="s", tile_m=10.0, overlap_m=3.0,
                       chunk_points=2000)
    index, tiles = read_tile_index(tmp_path / "i.json")
    per_tile = {t: _blob_detector(read_tile_points(tmp_path / "tiles" / f"{t}.npz").xyz)
                for t in tile_ids(tmp_path / "i.json")}
    merged, rows = merge_survey_detections(index, tiles, per_tile)
    ref, _ = detect_tiled(read_points(path).xyz, _blob_detector, 10.0, 3.0, progress=False)
    assert merged == ref
    assert len(merged) == 4 and sum(r["n_detections"] for r in rows) > len(merged)  # seams seen twice
    centres = np.array([d["box"][:2] for d in merged]) - UTM[:2]
    for c in ((10.1, 5.0), (5.0, 9.9), (20.05, 9.95), (25.0, 15.0)):
        assert np.sum(np.hypot(*(centres - c).T) < 0.15) == 1
    assert len(doc["tiles"]) == 6


def test_merge_refuses_a_lost_or_foreign_tile(tmp_path):
    path = tmp_path / "s.xyz"
    write_points(path, PointCloud(_blob_survey()))
    split_survey(path, tmp_path / "tiles", tmp_path / "i.json", survey="s", tile_m=12.0)
    index, tiles = read_tile_index(tmp_path / "i.json")
    per_tile = {t.id: [] for t in tiles}
    assert merge_survey_detections(index, tiles, per_tile)[0] == []
    lost = dict(per_tile)
    del lost["t001_000"]
    with pytest.raises(ValueError, match="missing: t001_000"):
        merge_survey_detections(index, tiles, lost)
    with pytest.raises(ValueError, match="t009_009"):
        merge_survey_detections(index, tiles, {**per_tile, "t009_009": []})


def test_merge_is_merge_tile_detections():
    """A duplicate fitted a millimetre to each side of a seam is reported once."""
    tiles = plan_tiles((UTM[0], UTM[1], UTM[0] + 20.0, UTM[1] + 10.0), 10.0, 3.0)
    index = {"survey": "s", "tiles": [{"id": t.id, "n_points": 10, "file": f"tiles/{t.id}.npz"} for t in tiles]}
    seam = UTM[0] + 10.0

    def det(x, score):
        return {"cls": "reef_ring", "box": [x, UTM[1] + 5.0, -11.0, 2.7, 2.7, 0.75, 0.0], "score": score}

    per_tile = {"t000_000": [det(seam - 0.001, 0.9)], "t001_000": [det(seam + 0.001, 0.8)]}
    merged, rows = merge_survey_detections(index, tiles, per_tile)
    assert merged == merge_tile_detections(per_tile, tiles) and len(merged) == 1
    assert [r["n_kept"] for r in rows] == [1, 1]


def test_outputs_are_in_the_survey_coordinates(tmp_path):
    dets = [{"cls": "reef_cone", "box": [550012.345678901, 4180003.21098765, -10.8, 2.0, 2.0, 1.37, 0.3],
             "score": 0.9, "pose": {"t": [550012.345678901, 4180003.21098765, -11.5], "q": [1.0, 0.0, 0.0, 0.0]},
             "extras": {"accepted": True}}]
    doc = write_survey_detections(dets, tmp_path / "d.json", tmp_path / "d.csv", tmp_path / "d.geojson",
                                  survey="line1", method="model_based_ours", source="data/line1.xyz",
                                  crs="EPSG:32610", classes=["reef_cone"])
    back = read_detections(tmp_path / "d.json", expected_scene="line1")
    assert back["detections"][0]["box"] == dets[0]["box"] and back["crs"] == "EPSG:32610" == doc["crs"]
    assert back["source"] == "data/line1.xyz"
    assert (tmp_path / "d.csv").read_text().startswith("cls,x,y,z,l,w,h,yaw_rad,score,lon,lat")  # no comment line
    assert pd.read_csv(tmp_path / "d.csv")["x"].tolist() == [550012.345678901]
    assert json.loads((tmp_path / "d.csv.json").read_text())["crs"] == "EPSG:32610"
    gj = json.loads((tmp_path / "d.geojson").read_text())  # RFC 7946: lon/lat, no crs member
    assert "crs" not in gj
    lon, lat = np.array(gj["features"][0]["geometry"]["coordinates"][0])[:4].mean(0)
    assert -124 < lon < -122 and 37 < lat < 38.5


def test_tile_index_of_another_version_is_refused(tmp_path):
    (tmp_path / "i.json").write_text(json.dumps({"schema_version": 99, "survey": "s", "crs": None, "origin": [0, 0, 0],
                                                 "n_points": 1, "bounds": [0, 0, 1, 1], "tile_m": 40, "overlap_m": 3,
                                                 "nx": 1, "ny": 1, "tiles": []}))
    with pytest.raises(ValueError, match="schema_version 99"):
        read_tile_index(tmp_path / "i.json")
    (tmp_path / "j.json").write_text("{}")
    with pytest.raises(ValueError, match="not a tile index"):
        read_tile_index(tmp_path / "j.json")


# -------------------------------------------------------------------------- end to end with snakemake
TILE_M, OVERLAP_M, EXTENT = 12.0, 3.0, (30.0, 20.0)
#: (class, x, y) in the survey's local frame: on the x seams (10, 20 m), the y seam (10 m), at a seam
#: crossing, and inside tiles.
LAYOUT = [("reef_ring", 10.1, 5.0), ("reef_cone", 5.0, 9.9), ("tetrapod_s", 19.8, 14.0), ("tetrapod_b", 15.0, 10.2),
          ("reef_cone", 20.05, 9.95), ("reef_ring", 25.0, 5.0), ("tetrapod_s", 4.0, 15.0)]
SMOKE_PARAMS = {"proposal_max_rounds_n": 2}


def _scene_survey(cfg):
    """A 30 m x 20 m MBES survey (one line set along x, the smoke config's 128-beam sensor) of an fBm
    seabed with the LAYOUT objects standing on it, in UTM coordinates: (points (N,3), [(cls, box)])."""
    from sonardet.geometry import quat_from_yaw, quat_to_matrix
    from sonardet.objects import build_object, canonical_box
    from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, survey_lines
    from sonardet.sim.seabed import make_seabed

    rng = np.random.default_rng(3)
    sensor = SensorConfig.from_dict(cfg["sensor"])
    built = {c: build_object(c, cfg["objects"]) for c in {c for c, _, _ in LAYOUT}}
    hf = make_seabed(EXTENT, cell_m=0.2, mean_depth_m=-11.5, slope_deg=1.0, amplitude_m=0.05, rng=rng)
    meshes, truth = [(hf.vertices(), hf.faces())], []
    for cls, x, y in LAYOUT:
        m = built[cls]
        q = quat_from_yaw(rng.uniform(0, 2 * np.pi))
        v = np.asarray(m.mesh.vertices) @ quat_to_matrix(q).T
        base = v[:, 2] < v[:, 2].min() + 0.05
        t = np.array([x, y, float(np.max(hf.height_at(v[base, 0] + x, v[base, 1] + y))) - v[:, 2].min()])
        meshes.append((v + t, np.asarray(m.mesh.faces)))
        truth.append((cls, canonical_box(m.mesh.vertices, t, q, m.symmetry_order) + np.r_[UTM, np.zeros(4)]))
    traj = survey_lines((0, EXTENT[0], 0, EXTENT[1]), "x", 0.0, 11.5, 0.3, sensor, run_in_m=1.0)
    xyz = scan(RaycastTarget(meshes), traj, sensor, np.random.default_rng(5)).xyz
    xyz = xyz[np.all((xyz[:, :2] >= 0) & (xyz[:, :2] <= EXTENT), axis=1)]
    return xyz + UTM, truth


@pytest.fixture(scope="module")
def survey_run(tmp_path_factory, smoke_config):
    """`snakemake --cores 2` of the survey target on the smoke config plus a `surveys` entry for a
    synthetic 30 m x 20 m survey (12 m tiles: 3 x 2 tiles) in UTM coordinates, read in 5000-point chunks.
    The default config's real line is also configured, at a path that does not exist from here."""
    work = tmp_path_factory.mktemp("survey")
    copy_workflow(work)
    xyz, truth = _scene_survey(smoke_config)
    (work / "data").mkdir()
    write_points(work / "data" / "reef_test.xyz.gz", PointCloud(xyz))
    cfg = (REPO / "tests" / "config" / "smoke.yaml").read_text() + (
        "\nsurveys:\n  reef_test:\n    path: data/reef_test.xyz.gz\n    crs: EPSG:32610\n"
        f"    tile_m: {TILE_M}\n    overlap_m: {OVERLAP_M}\n    chunk_points: 5000\n")
    (work / "config_survey.yaml").write_text(cfg)
    # The target first: --configfile takes every argument after it.
    cmd = [sys.executable, "-m", "snakemake", "results/surveys/reef_test/detections.json", "--cores", "2",
           "--configfile", "config_survey.yaml"]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return SimpleNamespace(work=work, truth=truth, log=proc.stdout + proc.stderr, seconds=seconds,
                           out=work / "results" / "surveys" / "reef_test")


@pytest.mark.slow
def test_one_job_per_tile(survey_run):
    index = json.loads((survey_run.out / "tile_index.json").read_text())
    tiles = sorted(t["id"] for t in index["tiles"] if t["file"])
    assert (index["nx"], index["ny"]) == (3, 2) and len(tiles) == 6
    assert index["n_points"] > 20000 and index["chunk_points"] == 5000 and index["streamed"]
    for kind, ext in (("logs", "log"), ("benchmarks", "tsv")):
        folder = survey_run.work / "results" / kind / "detect_survey_tile" / "reef_test"
        assert sorted(p.stem for p in folder.glob(f"*.{ext}")) == tiles
    assert sorted(p.stem for p in (survey_run.out / "tile_detections").glob("*.json")) == tiles
    assert survey_run.log.count("(Rule: detect_survey_tile)") == 6  # six jobs finished
    assert survey_run.log.count("(Rule: survey_tiles)") == survey_run.log.count("(Rule: survey_detections)") == 1
    for rule in ("survey_tiles", "survey_detections"):
        assert (survey_run.work / "results" / "logs" / rule / "reef_test.log").is_file()
        assert (survey_run.work / "results" / "benchmarks" / rule / "reef_test.tsv").is_file()
    # The real line of the default config is not at ../shared from the test's folder: reported, left out.
    assert "surveys.r2sonic_sfbay.path ../shared/data/real/r2sonic_sfbay.xyz.gz not found" in survey_run.log
    # Nothing left to do on a second run (the checkpoint and its tiles are stable).
    dry = subprocess.run([sys.executable, "-m", "snakemake", "results/surveys/reef_test/detections.json", "-n",
                          "--configfile", "config_survey.yaml"], cwd=survey_run.work, capture_output=True, text=True)
    assert dry.returncode == 0 and "Nothing to be done" in dry.stdout + dry.stderr
    print(f"survey workflow: {survey_run.seconds:.1f} s")


@pytest.mark.slow
def test_merged_detections_equal_the_cli_and_have_no_duplicate(survey_run, tmp_path):
    """The workflow's merge equals `sonardet detect` (the one-process tiled path, detect_tiled) on the same
    file with the same models, tile size and detector settings, centres within 0.05 m; every object is
    found once, seam objects included."""
    from sonardet.cli import main

    doc = read_detections(survey_run.out / "detections.json", expected_scene="reef_test")
    assert doc["method"] == "model_based_ours" and doc["crs"] == "EPSG:32610"
    cli_out = tmp_path / "reef_test.json"
    assert main(["detect", "--input", str(survey_run.work / "data" / "reef_test.xyz.gz"), "--out", str(cli_out),
                 "--results", str(survey_run.work / "results"), "--crs", "EPSG:32610", "--tile-m", str(TILE_M),
                 "--overlap-m", str(OVERLAP_M), "--params", json.dumps(SMOKE_PARAMS)]) == 0
    ref = read_detections(cli_out)["detections"]
    got = doc["detections"]
    assert len(got) == len(ref) > 0
    pairs = match_by_centre(got, ref)
    assert all(a["cls"] == b["cls"] and d < 0.05 and a["score"] == pytest.approx(b["score"], abs=1e-6)
               for a, b, d in pairs)
    # Each object once: one accepted detection within 0.1 m of every object, none near another.
    acc = [d for d in got if d["extras"]["accepted"]]
    truth = [{"cls": c, "box": list(b)} for c, b in survey_run.truth]
    assert len(acc) == len(truth)
    assert all(a["cls"] == t["cls"] and d < 0.1 for a, t, d in match_by_centre(acc, truth))
    c = np.array([d["box"][:2] for d in acc])
    dist = np.hypot(*(c[:, None] - c[None]).transpose(2, 0, 1))
    assert dist[np.triu_indices(len(c), 1)].min() > 1.0


@pytest.mark.slow
def test_outputs_in_the_survey_coordinates(survey_run):
    doc = json.loads((survey_run.out / "detections.json").read_text())
    index = json.loads((survey_run.out / "tile_index.json").read_text())
    assert index["origin"] == [550000.0, 4180000.0, 0.0] and index["crs"] == "EPSG:32610"
    dets = doc["detections"]
    boxes = np.array([d["box"] for d in dets])
    lo, hi = np.array(index["bounds"][:2]), np.array(index["bounds"][2:])
    assert np.all(boxes[:, :2] > lo - 2.0) and np.all(boxes[:, :2] < hi + 2.0)  # UTM, not local
    assert np.all(boxes[:, 0] > 5e5) and np.all(boxes[:, 1] > 4e6)
    df = pd.read_csv(survey_run.out / "detections.csv")
    assert df[["x", "y", "z"]].to_numpy().tolist() == boxes[:, :3].tolist()  # bit-identical
    assert json.loads((survey_run.out / "detections.csv.json").read_text())["crs"] == "EPSG:32610"
    assert "crs" not in json.loads((survey_run.out / "detections.geojson").read_text())  # RFC 7946, WGS 84
    gj = json.loads((survey_run.out / "detections_crs.geojson").read_text())
    assert gj["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32610" and len(gj["features"]) == len(dets)
    ring = np.array(gj["features"][0]["geometry"]["coordinates"][0])
    assert np.allclose(ring[:4].mean(0), boxes[0, :2], rtol=0, atol=1e-6)
    summary = json.loads((survey_run.out / "summary.json").read_text())
    assert summary["n_tiles"] == 6 and summary["n_detections"] == len(dets)
    assert sum(r["n_points"] for r in summary["tiles"]) > summary["n_points"]  # overlaps counted per tile
    # The classified soundings: every sounding of the survey once, objects' soundings in class 43.
    las = read_points(survey_run.out / "soundings.laz")
    assert len(las) == index["n_points"] and las.crs == "EPSG:32610"
    ids = las.attributes["object_id"]
    assert set(np.unique(las.attributes["classification"])) == {2, 43}
    assert set(np.unique(ids[ids >= 0])) == set(range(len(dets)))
    assert (survey_run.out / "objects.ply").read_bytes().startswith(b"ply")
    # A tile file: the survey's float64 coordinates with the local origin beside them.
    cloud = read_points(survey_run.out / "tiles" / "t001_000.npz")
    assert cloud.xyz[:, 0].min() > 5e5 and np.array_equal(cloud.origin, index["origin"])
