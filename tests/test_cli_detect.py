"""`sonardet detect` and the CSV/GeoJSON exports: survey files in UTM coordinates in, detections in the
same coordinates out; bad input gives a readable error and a non-zero exit, never a traceback.

Hard cases named in the tests: UTM offsets (5.5e5, 4.18e6) kept to full float64 precision through
JSON, CSV and GeoJSON; a CRS from the file (LAS) or from --crs, and the two contradicting; a survey
tiled by the CLI; the real R2Sonic line (bare seabed, EPSG:32610); a missing file, a wrong column
count, NaN coordinates, a missing template file, an overlap smaller than the objects, bad --params.
"""

from __future__ import annotations

import json
import logging
import math
import re
import shutil
import subprocess
import sys
import time

import numpy as np
import pandas as pd
import pytest
from conftest import REAL_FILE, match_by_centre, needs_real

from sonardet.cli import main
from sonardet.io.annotations import read_detections
from sonardet.io.export import crs_urn, write_detections_csv, write_detections_geojson, write_detections_geojson_crs
from sonardet.io.points import PointCloud, read_points, write_points

UTM = np.array([5.5e5, 4.18e6, 0.0])
SEABED_Z = -11.5
TEMPLATE_CFG = {"yaw_deg": [0, 60], "directions": ["x", "y"], "offsets_m": [-7.5, 0.0, 7.5], "altitude_m": 11.5}


@pytest.fixture(scope="module")
def results_dir(tmp_path_factory, built_objects, default_config):
    """A results folder as the workflow writes it: objects/{cls}.json|.ply and templates/{cls}.npz
    (templates from a reduced set of views, to keep the tests fast)."""
    from sonardet.objects import write_object
    from sonardet.sim.mbes import SensorConfig
    from sonardet.io.templates import write_templates
    from sonardet.sim.templates import scan_templates

    root = tmp_path_factory.mktemp("results")
    sensor = SensorConfig.from_dict(default_config["sensor"])
    for cls, m in built_objects.items():
        write_object(m, default_config["objects"]["density_kg_m3"], root / "objects" / f"{cls}.ply",
                    root / "objects" / f"{cls}.json")
        tv = scan_templates(cls, m.mesh.vertices, m.mesh.faces, m.symmetry_order, TEMPLATE_CFG, sensor,
                            np.random.default_rng(1))
        write_templates(root / "templates" / f"{cls}.npz", tv)
    return root


@pytest.fixture(scope="module")
def survey(built_objects, default_config):
    """One MBES line over a flat 14 m x 14 m seabed with a tetrapod_s and a reef_cone, shifted to UTM
    coordinates (float64): (points (N,3), [(cls, true box in UTM)])."""
    from sonardet.geometry import quat_from_yaw, quat_to_matrix
    from sonardet.objects import canonical_box
    from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, straight_line

    sensor = SensorConfig.from_dict(default_config["sensor"])
    lo, hi = -2.0, 16.0
    meshes = [(np.array([[lo, lo, SEABED_Z], [hi, lo, SEABED_Z], [hi, hi, SEABED_Z], [lo, hi, SEABED_Z]]),
               np.array([[0, 1, 2], [0, 2, 3]]))]
    truth = []
    for cls, x, y, yaw in (("tetrapod_s", 6.6, 5.5, 0.7), ("reef_cone", 9.5, 7.4, 0.0)):
        m = built_objects[cls]
        q = quat_from_yaw(yaw)
        v = np.asarray(m.mesh.vertices) @ quat_to_matrix(q).T
        t = np.array([x, y, SEABED_Z - v[:, 2].min()])
        meshes.append((v + t, np.asarray(m.mesh.faces)))
        truth.append((cls, canonical_box(m.mesh.vertices, t, q, m.symmetry_order) + np.r_[UTM, np.zeros(4)]))
    traj = straight_line((-1.0, 11.0), (15.0, 11.0), 0.0, sensor, -SEABED_Z)
    xyz = scan(RaycastTarget(meshes), traj, sensor, np.random.default_rng(0)).xyz
    xyz = xyz[np.all((xyz[:, :2] >= 0) & (xyz[:, :2] <= 14.0), axis=1)]
    return xyz + UTM, truth


@pytest.fixture(scope="module")
def survey_xyz(survey, tmp_path_factory):
    """The survey as a headerless x y z text file (full float64 precision), as hydrographic software
    exports it."""
    path = tmp_path_factory.mktemp("survey") / "line_0007.xyz"
    write_points(path, PointCloud(survey[0]))
    return path


def _accepted(dets):
    return [d for d in dets if d["extras"]["accepted"]]


def _near(dets, box, tol_m):
    return [d for d in dets if np.linalg.norm(np.subtract(d["box"][:3], box[:3])) < tol_m]


FIXED_METHOD = """
from sonardet import methods
from sonardet.methods import Method, MethodFamily


class Fixed(MethodFamily):
    name, label, prefix = "fixed", "test", "fixed"

    def methods(self, config):
        return []  # not configured: it is run by name only, so other tests' method lists stay the default

    def parse(self, name, config):
        return Method(name="fixed", family="fixed", resources=()) if name == "fixed" else None

    def load(self, method, resources):
        def detector(xyz):
            c = xyz.mean(0)
            box = [float(c[0]), float(c[1]), float(c[2]), 1.0, 1.0, 1.0, 0.0]
            return ([{"cls": "reef_cone", "box": box, "score": 0.9, "extras": {"accepted": True}},
                     {"cls": "reef_ring", "box": box, "score": 0.05, "extras": {"accepted": False}}],
                    {"seconds": {"total": 0.0}})
        return detector


methods.register(Fixed())
"""


def test_all_hypotheses_on_request(survey_xyz, tmp_path):
    """Only the boxes a method accepted are written unless `--all-hypotheses`; a method registered by
    a plugin (`--plugins`) runs like the built-in ones."""
    plugin = tmp_path / "fixed_method.py"
    plugin.write_text(FIXED_METHOD)
    common = ["detect", "--input", str(survey_xyz), "--method", "fixed", "--plugins", str(plugin)]
    assert main([*common, "--out", str(tmp_path / "acc.json")]) == 0
    assert [d["cls"] for d in read_detections(tmp_path / "acc.json")["detections"]] == ["reef_cone"]
    assert main([*common, "--out", str(tmp_path / "all.json"), "--all-hypotheses"]) == 0
    dets = read_detections(tmp_path / "all.json")["detections"]
    assert [(d["cls"], d["extras"]["accepted"]) for d in dets] == [("reef_cone", True), ("reef_ring", False)]


def test_detect_writes_json_csv_geojson_in_utm(survey, survey_xyz, results_dir, tmp_path, capsys):
    out = tmp_path / "line_0007.json"
    rc = main(["detect", "--input", str(survey_xyz), "--out", str(out), "--csv", str(tmp_path / "d.csv"),
               "--geojson-crs", str(tmp_path / "d.geojson"), "--results", str(results_dir), "--crs", "EPSG:32610"])
    assert rc == 0
    summary = capsys.readouterr().out
    assert summary.startswith("sonardet detect: line_0007.xyz:") and "EPSG:32610" in summary
    # JSON: the project's reader accepts it with its default checks (scene id = file stem).
    doc = read_detections(out)
    assert doc["scene"] == "line_0007" and doc["method"] == "model_based_ours" and doc["crs"] == "EPSG:32610"
    dets = doc["detections"]
    acc = _accepted(dets)
    assert acc == dets  # accepted objects only, unless --all-hypotheses
    assert sorted(d["cls"] for d in acc) == ["reef_cone", "tetrapod_s"]
    for cls, box in survey[1]:
        hit = _near(acc, box, 0.1)
        assert len(hit) == 1 and hit[0]["cls"] == cls, f"{cls} not found within 0.1 m of {box[:3]}"
        assert np.allclose(hit[0]["pose"]["t"][:2], box[:2], atol=0.2)  # the pose is in UTM as well
    # CSV: one row per detection, the same float64 values (full repr, not rounded), lon/lat, quaternions;
    # no comment line (QGIS reads it as is), the metadata in the sidecar.
    df = pd.read_csv(tmp_path / "d.csv")
    assert list(df.columns) == ["cls", "x", "y", "z", "l", "w", "h", "yaw_rad", "score", "lon", "lat", "qw", "qx",
                                "qy", "qz"]
    side = json.loads((tmp_path / "d.csv.json").read_text())
    assert side["crs"] == "EPSG:32610" and side["source"] == str(survey_xyz) and side["n_rows"] == len(dets)
    assert len(df) == len(dets)
    for (_, row), d in zip(df.iterrows(), dets):
        assert row["cls"] == d["cls"]
        assert [row[c] for c in ("x", "y", "z", "l", "w", "h", "yaw_rad")] == d["box"]  # bit-identical
        assert row["score"] == d["score"] and [row[c] for c in ("qw", "qx", "qy", "qz")] == d["pose"]["q"]
    # GeoJSON in the input CRS: box footprints in UTM with the CRS named.
    gj = json.loads((tmp_path / "d.geojson").read_text())
    assert gj["type"] == "FeatureCollection"
    assert gj["crs"] == {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32610"}}
    assert len(gj["features"]) == len(dets)
    for f, d in zip(gj["features"], dets):
        ring = np.array(f["geometry"]["coordinates"][0])
        assert f["geometry"]["type"] == "Polygon" and ring.shape == (5, 2) and np.array_equal(ring[0], ring[-1])
        assert np.allclose(ring[:4].mean(0), d["box"][:2], rtol=0, atol=1e-6)
        assert f["properties"]["cls"] == d["cls"] and f["properties"]["z"] == d["box"][2]
        assert ring.min(0)[0] > 5e5 and ring.min(0)[1] > 4e6


def test_cli_tiles_a_survey_larger_than_a_tile(survey, survey_xyz, results_dir, tmp_path, caplog, capsys):
    """--tile-m 7 cuts the 14 m survey into 2 x 2 tiles with seams near x = 7 and y = 7, which the
    tetrapod and the cone straddle: same objects as one tile, each once."""
    single, tiled = tmp_path / "single.json", tmp_path / "tiled.json"
    common = ["--input", str(survey_xyz), "--results", str(results_dir), "--crs", "EPSG:32610"]
    assert main(["detect", "--out", str(single), *common]) == 0
    with caplog.at_level(logging.INFO):
        assert main(["detect", "--out", str(tiled), "--tile-m", "7", "--overlap-m", "3", *common]) == 0
    assert "tile 1/4" in caplog.text and "tile 4/4" in caplog.text
    assert "4 tile(s)" in capsys.readouterr().out
    a = _accepted(read_detections(single)["detections"])
    b = _accepted(read_detections(tiled)["detections"])
    assert len(a) == len(b) == 2
    for d in a:
        match = _near(b, d["box"], 0.05)
        assert len(match) == 1 and match[0]["cls"] == d["cls"]


def test_cli_jobs_give_the_detections_of_one_process(survey_xyz, results_dir, tmp_path, capsys):
    """--jobs 2 runs the 4 tiles of --tile-m 7 in two worker processes: every output file is the same bytes
    as with --jobs 1; the summary line gives the soundings per second and the jobs used."""
    common = ["--input", str(survey_xyz), "--results", str(results_dir), "--crs", "EPSG:32610", "--tile-m", "7",
              "--overlap-m", "3", "--all-hypotheses"]
    outs = {}
    for jobs in ("1", "2"):
        d = tmp_path / f"j{jobs}"
        d.mkdir()
        assert main(["detect", "--out", str(d / "survey.json"), "--csv", str(d / "survey.csv"),
                     "--geojson", str(d / "survey.geojson"), "--jobs", jobs, *common]) == 0
        outs[jobs] = {p.name: p.read_bytes() for p in sorted(d.iterdir())}
        line = capsys.readouterr().out
        assert re.search(r"4 tile\(s\), .* s detection \(\d+ soundings/s" + (r", 2 jobs\)" if jobs == "2" else r"\)"),
                         line), line
    assert outs["1"] == outs["2"] and len(outs["1"]) == 4  # json, csv + its sidecar, geojson
    assert read_detections(tmp_path / "j1" / "survey.json")["detections"]


def test_crs_comes_from_the_file(survey, results_dir, tmp_path, capsys):
    las = tmp_path / "survey.las"
    write_points(las, PointCloud(survey[0], crs="EPSG:32610"))
    gj = tmp_path / "d.geojson"
    assert main(["detect", "--input", str(las), "--out", str(tmp_path / "survey.json"), "--geojson-crs", str(gj),
                 "--results", str(results_dir), "--classes", "reef_cone", "tetrapod_s"]) == 0
    assert json.loads(gj.read_text())["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32610"
    assert read_detections(tmp_path / "survey.json")["crs"] == "EPSG:32610"
    # A --crs contradicting the file's is refused.
    capsys.readouterr()
    assert main(["detect", "--input", str(las), "--out", str(tmp_path / "x.json"), "--crs", "EPSG:32633",
                 "--results", str(results_dir)]) == 2
    err = capsys.readouterr().err
    assert "survey.las" in err and "EPSG:32610" in err and "Traceback" not in err
    assert not (tmp_path / "x.json").exists()


def _write(path, text):
    path.write_text(text)
    return path


@pytest.mark.parametrize("name,content,pattern", [
    ("missing.xyz", None, r"missing\.xyz: no such point-cloud file"),
    ("cols.xyz", "554800.1 4179000.2 -10.5\n554800.2 4179000.3\n", r"cols\.xyz line 2: expected 3 columns, found 2"),
    ("cols.csv", "x,y,z\n554800.1,4179000.2,-10.5\n554800.2,4179000.3,-10.4,7\n",
     r"cols\.csv line 3: expected 3 columns, found 4"),
    ("nan.xyz", "554800.1 4179000.2 -10.5\n554800.2 4179000.3 -10.4\n554800.3 nan -10.4\n",
     r"nan\.xyz line 3 .*non-finite coordinates"),
    ("inf.xyz.gz", None, r"inf\.xyz\.gz line 2 .*non-finite"),
    ("empty.xyz", "# header comment only\n", r"empty\.xyz: no points"),
    ("survey.e57", "", r"survey\.e57: unsupported point-cloud suffix"),
])
def test_bad_input_is_a_readable_error(results_dir, tmp_path, capsys, name, content, pattern):
    import gzip

    path = tmp_path / name
    if name == "inf.xyz.gz":
        path.write_bytes(gzip.compress(b"554800.1 4179000.2 -10.5\n554800.2 inf -10.4\n"))
    elif content is not None:
        _write(path, content)
    out = tmp_path / "o.json"
    assert main(["detect", "--input", str(path), "--out", str(out), "--results", str(results_dir)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("sonardet detect: error: ") and "Traceback" not in err
    assert re.search(pattern, err), err
    assert not out.exists()


@pytest.mark.parametrize("args,pattern", [
    (["--overlap-m", "2"], r"overlap_m = 2 m is smaller than the largest object footprint \(2\.\d+ m\)"),
    (["--tile-m", "0"], r"tile_m must be a positive"),
    (["--jobs", "0"], r"--jobs 0: the number of tiles detected at once must be at least 1"),
    (["--params", '{"voxel": 0.1}'], r"unknown model-based detector parameter 'voxel'"),
    (["--params", "{voxel"], r"--params: not valid JSON"),
    (["--params", "[1, 2]"], r"neither a JSON object nor an existing JSON file"),
    (["--classes", "reef_boulder"], r"objects/reef_boulder\.json: missing"),
])
def test_bad_options_are_readable_errors(survey_xyz, results_dir, tmp_path, capsys, args, pattern):
    rc = main(["detect", "--input", str(survey_xyz), "--out", str(tmp_path / "o.json"), "--results",
               str(results_dir), *args])
    err = capsys.readouterr().err
    assert rc == 2 and re.search(pattern, err), err
    assert "Traceback" not in err


def test_params_from_a_json_file(survey_xyz, results_dir, tmp_path):
    params = _write(tmp_path / "p.json", json.dumps({"accept_min": 0.99, "keep_rejected": False}))
    assert main(["detect", "--input", str(survey_xyz), "--out", str(tmp_path / "o.json"), "--results",
                 str(results_dir), "--params", str(params), "--classes", "reef_cone"]) == 0
    assert read_detections(tmp_path / "o.json")["detections"] == []  # nothing reaches a score of 0.99


def test_missing_templates_name_the_file_and_the_make_target(survey_xyz, results_dir, tmp_path, capsys):
    partial = tmp_path / "results"
    shutil.copytree(results_dir / "objects", partial / "objects")
    (partial / "templates").mkdir()
    for cls in ("reef_cone", "tetrapod_s"):
        shutil.copy(results_dir / "templates" / f"{cls}.npz", partial / "templates")
    argv = ["detect", "--input", str(survey_xyz), "--out", str(tmp_path / "o.json"), "--results", str(partial)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "templates/reef_ring.npz: missing" in err
    assert "snakemake --cores 2 results/templates/reef_ring.npz" in err and "Traceback" not in err
    # The classes that are there can still be detected.
    assert main(argv + ["--classes", "reef_cone", "tetrapod_s"]) == 0


def test_console_error_exit_code_without_traceback(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "sonardet.cli", "detect", "--input", str(tmp_path / "nope.laz"),
                           "--out", str(tmp_path / "o.json"), "--results", str(tmp_path)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert "sonardet detect: error:" in proc.stderr and "objects/reef_ring.json: missing" in proc.stderr


@needs_real
def test_real_r2sonic_line(results_dir, tmp_path, capsys):
    """The real line (236k soundings, bare seabed with a 0.5 m pit, EPSG:32610, two 40 m tiles): runs,
    finds at most a stray fit or two, and reports in UTM."""
    out, csv, gj = tmp_path / "r2sonic_sfbay.json", tmp_path / "r.csv", tmp_path / "r.geojson"
    t = time.perf_counter()
    assert main(["detect", "--input", str(REAL_FILE), "--out", str(out), "--csv", str(csv), "--geojson", str(gj),
                 "--results", str(results_dir), "--crs", "EPSG:32610"]) == 0
    seconds = time.perf_counter() - t
    summary = capsys.readouterr().out
    assert "236287 points" in summary and "2 tile(s)" in summary
    doc = read_detections(out)
    assert doc["crs"] == "EPSG:32610" and doc["source"] == str(REAL_FILE)
    dets = doc["detections"]
    assert len(_accepted(dets)) <= 2, [(d["cls"], d["box"][:3], d["score"]) for d in dets]
    for d in dets:  # inside the line's bounding box (README), in UTM
        assert 554805 < d["box"][0] < 554849 and 4178984 < d["box"][1] < 4179042
    assert len(pd.read_csv(csv)) == len(dets)
    assert "crs" not in json.loads(gj.read_text())  # RFC 7946: WGS 84 lon/lat
    assert seconds < 120


# --------------------------------------------------------------------------------------------- exports
def _det(box, score=0.5, pose=True):
    d = {"cls": "tetrapod_b", "box": list(box), "score": score, "extras": {"accepted": True}}
    if pose:
        d["pose"] = {"t": list(box[:3]), "q": [math.cos(0.3), 0.0, 0.0, math.sin(0.3)]}
    return d


def test_csv_keeps_full_precision_and_pose_columns_only_with_poses(tmp_path):
    box = [554812.123456789, 4179012.987654321, -10.123456789, 2.1, 2.0, 1.9, 0.6]
    write_detections_csv(tmp_path / "a.csv", [_det(box)])
    df = pd.read_csv(tmp_path / "a.csv")
    assert df["x"][0] == box[0] and df["y"][0] == box[1]  # not rounded to cm
    assert list(df.columns)[-4:] == ["qw", "qx", "qy", "qz"]
    write_detections_csv(tmp_path / "b.csv", [_det(box, pose=False)])
    lines = (tmp_path / "b.csv").read_text().splitlines()
    assert lines[0] == "cls,x,y,z,l,w,h,yaw_rad,score"  # no CRS: no lon/lat columns
    # Mixed: the columns are there, empty for the detection without a pose.
    write_detections_csv(tmp_path / "c.csv", [_det(box), _det(box, pose=False)])
    df = pd.read_csv(tmp_path / "c.csv")
    assert df["qw"].isna().tolist() == [False, True]
    write_detections_csv(tmp_path / "d.csv", [])
    assert (tmp_path / "d.csv").read_text() == "cls,x,y,z,l,w,h,yaw_rad,score\n"


def test_geojson_footprint_of_a_rotated_box(tmp_path):
    box = [554812.5, 4179012.5, -10.0, 4.0, 2.0, 1.0, math.pi / 2]  # l along y after the rotation
    doc = write_detections_geojson_crs(tmp_path / "a.geojson", [_det(box)], crs="epsg:32610")
    assert json.loads((tmp_path / "a.geojson").read_text()) == doc
    ring = np.array(doc["features"][0]["geometry"]["coordinates"][0])
    assert np.allclose(ring.max(0) - ring.min(0), [2.0, 4.0], atol=1e-9)
    assert np.allclose(ring[:4].mean(0), box[:2], atol=1e-9)
    x, y = ring[:, 0] - box[0], ring[:, 1] - box[1]
    assert 0.5 * np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) == pytest.approx(8.0)  # counter-clockwise
    props = doc["features"][0]["properties"]
    assert props == {"cls": "tetrapod_b", "score": 0.5, "z": -10.0, "h": 1.0, "l": 4.0, "w": 2.0,
                     "yaw": math.pi / 2, "accepted": True}
    assert doc["crs"]["properties"]["name"] == "urn:ogc:def:crs:EPSG::32610"


def test_geojson_crs_member(tmp_path, caplog):
    assert crs_urn("EPSG:32610") == "urn:ogc:def:crs:EPSG::32610" and crs_urn(" epsg: 4326 ") == \
        "urn:ogc:def:crs:EPSG::4326"
    assert crs_urn("urn:ogc:def:crs:EPSG::25832") == "urn:ogc:def:crs:EPSG::25832" and crs_urn(None) is None
    assert crs_urn("EPSG:32610+5703") == "urn:ogc:def:crs:EPSG::32610"  # the horizontal part: 2-D positions
    assert "crs" not in write_detections_geojson_crs(tmp_path / "a.geojson", [], crs=None)
    with pytest.raises(ValueError, match="RFC 7946 GeoJSON is in longitude/latitude"):
        write_detections_geojson(tmp_path / "c.geojson", [], crs=None)
    with caplog.at_level(logging.WARNING):
        doc = write_detections_geojson_crs(tmp_path / "b.geojson", [], crs='PROJCS["local",UNIT["metre",1]]')
    assert "crs" not in doc and "not an EPSG code" in caplog.text


def test_exports_refuse_non_finite_values_and_keep_the_old_file(tmp_path):
    good = [_det([1.0, 2.0, -10.0, 2.0, 2.0, 1.0, 0.0])]
    bad = good + [_det([np.nan, 2.0, -10.0, 2.0, 2.0, 1.0, 0.0])]
    for writer, name in ((write_detections_csv, "a.csv"), (write_detections_geojson_crs, "a.geojson")):
        writer(tmp_path / name, good)
        before = (tmp_path / name).read_bytes()
        with pytest.raises(ValueError, match="detection 1"):
            writer(tmp_path / name, bad)
        assert (tmp_path / name).read_bytes() == before
        assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


@needs_real
def test_detect_with_a_learned_method(tmp_path, one_torch_thread):
    """`sonardet detect --method sasa_100 --model ...` runs the learned detector on a survey file like the
    model-based one: outputs in the input's CRS (here the real R2Sonic line, UTM 10N)."""
    from test_sasa_model import CLASSES, TINY, make_scene

    from sonardet.detect.sasa import train

    (tmp_path / "scenes").mkdir()
    scenes = [make_scene(tmp_path / "scenes", f"s{i:04d}", i, CLASSES) for i in range(2)]
    model_dir = tmp_path / "models" / "sasa_100"
    train([str(p) for p in scenes], [], {**TINY, "classes": CLASSES}, model_dir)
    out = tmp_path / "r2sonic.json"
    rc = main(["detect", "--method", "sasa_100", "--model", str(model_dir / "model.pt"), "--input", str(REAL_FILE),
               "--crs", "EPSG:32610", "--out", str(out), "--csv", str(tmp_path / "r2sonic.csv")])
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["method"] == "sasa_100" and doc["crs"] == "EPSG:32610"
    for d in doc["detections"]:  # an untrained-for-this-seabed model may find some: they are in UTM
        assert 5.5e5 < d["box"][0] < 5.6e5 and 4.17e6 < d["box"][1] < 4.19e6
    # A learned method without its model is refused naming the file and how to make it.
    rc = main(["detect", "--method", "sasa_50", "--results", str(tmp_path), "--input", str(REAL_FILE),
               "--out", str(tmp_path / "x.json")])
    assert rc == 2


# ------------------------------------------------------------------------- surveyors' inputs, GIS outputs
def grid_geotiff(xyz, cell_m, path, crs="EPSG:32610", z_sign=1.0, nodata=-9999.0):
    """A GeoTIFF of soundings xyz (N,3) m: the mean z of the soundings in each cell of `cell_m` (north-up),
    nodata where a cell holds none (float64 band, the CRS given or none)."""
    import rasterio
    from rasterio.transform import from_origin

    x0, y1 = np.floor(xyz[:, 0].min() / cell_m) * cell_m, np.ceil(xyz[:, 1].max() / cell_m) * cell_m
    cols = np.floor((xyz[:, 0] - x0) / cell_m).astype(int)
    rows = np.floor((y1 - xyz[:, 1]) / cell_m).astype(int)
    w, h = cols.max() + 1, rows.max() + 1
    flat = rows * w + cols
    count = np.bincount(flat, minlength=w * h)
    mean = np.bincount(flat, weights=xyz[:, 2], minlength=w * h) / np.maximum(count, 1)
    grid = np.where(count > 0, z_sign * mean, nodata).reshape(h, w)
    with rasterio.open(path, "w", driver="GTiff", width=w, height=h, count=1, dtype="float64", crs=crs,
                       transform=from_origin(x0, y1, cell_m, cell_m), nodata=nodata) as ds:  # noqa: E501
        ds.write(grid, 1)
    return path


def lonlat_csv(xyz, path, crs="EPSG:32610"):
    """The soundings as a lon,lat,depth CSV (WGS 84 degrees, depth positive down), full float64 repr."""
    import pyproj

    lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(xyz[:, 0], xyz[:, 1])
    pd.DataFrame({"lon": lon, "lat": lat, "depth": -xyz[:, 2]}).to_csv(path, index=False, float_format="%.17g")
    return path


def test_same_detections_from_xyz_geotiff_and_lonlat(survey, survey_xyz, results_dir, tmp_path):
    """A synthetic survey with a tetrapod and a cone: the detections from the soundings (x y z), from a
    0.1 m GeoTIFF of them and from lon/lat (depth positive down) agree within 0.05 m, in EPSG:32610."""
    xyz = survey[0]
    tif = grid_geotiff(xyz, 0.1, tmp_path / "line.tif")
    ll = lonlat_csv(xyz, tmp_path / "line_ll.csv")
    common = ["--results", str(results_dir), "--classes", "reef_cone", "tetrapod_s"]
    docs = {}
    for name, args in (("xyz", ["--input", str(survey_xyz), "--crs", "EPSG:32610"]), ("tif", ["--input", str(tif)]),
                       ("ll", ["--input", str(ll)])):
        assert main(["detect", *args, "--out", str(tmp_path / f"{name}.json"), *common]) == 0
        docs[name] = read_detections(tmp_path / f"{name}.json")
    assert docs["ll"]["crs"] == "EPSG:32610" and docs["ll"]["input_crs"] == "EPSG:4326"
    assert docs["tif"]["crs"] == docs["xyz"]["crs"] == "EPSG:32610"
    ref = docs["xyz"]["detections"]
    assert sorted(d["cls"] for d in ref) == ["reef_cone", "tetrapod_s"]
    for name in ("tif", "ll"):
        got = docs[name]["detections"]
        pairs = match_by_centre(got, ref)
        assert len(got) == len(ref) == len(pairs), name
        assert all(a["cls"] == b["cls"] and dist < 0.05 for a, b, dist in pairs), (name, pairs)


def test_gis_and_cloudcompare_outputs(survey, survey_xyz, results_dir, tmp_path):
    """--geojson is RFC 7946 (a GIS reader sees EPSG:4326 polygons over the objects), --geojson-crs the
    same in UTM; --las holds every sounding once, classified (2 seabed, 43 in a detected box) with the
    detection and class indices; --meshes the posed class meshes with float64 vertices in UTM."""
    import laspy
    import pyogrio
    import pyproj
    import trimesh

    out = {k: tmp_path / n for k, n in (("json", "line_0007.json"), ("gj", "d.geojson"), ("gjc", "d_utm.geojson"),
                                         ("las", "d.laz"), ("ply", "d.ply"))}
    assert main(["detect", "--input", str(survey_xyz), "--crs", "EPSG:32610", "--out", str(out["json"]),
                 "--geojson", str(out["gj"]), "--geojson-crs", str(out["gjc"]), "--las", str(out["las"]),
                 "--meshes", str(out["ply"]), "--results", str(results_dir), "--quiet"]) == 0
    dets = read_detections(out["json"])["detections"]
    assert len(dets) == 2
    info = pyogrio.read_info(out["gj"])
    assert info["crs"] == "EPSG:4326" and info["features"] == 2 and info["geometry_type"] == "Polygon"
    assert pyogrio.read_info(out["gjc"])["crs"] == "EPSG:32610"
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32610", always_xy=True)
    for f, d in zip(json.loads(out["gj"].read_text())["features"], dets):
        ring = np.array(f["geometry"]["coordinates"][0])
        x, y = to_utm.transform(ring[:4, 0], ring[:4, 1])
        assert np.allclose([np.mean(x), np.mean(y)], d["box"][:2], atol=1e-3)
    las = laspy.read(out["las"])
    assert las.header.parse_crs().to_epsg() == 32610 and las.header.point_count == len(survey[0])
    assert np.allclose(np.c_[las.x, las.y, las.z], survey[0], rtol=0, atol=0.0006)  # 1 mm scale
    cls = np.asarray(las.classification)
    assert set(np.unique(cls)) == {2, 43}
    ids = np.asarray(las["object_id"])
    assert np.array_equal(ids >= 0, cls == 43) and set(np.unique(ids[ids >= 0])) == {0, 1}
    classes = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]  # the default config's order
    for k, d in enumerate(dets):
        inside = ids == k
        assert inside.sum() > 50 and np.all(np.asarray(las["cls"])[inside] == classes.index(d["cls"]))
        centre = np.c_[las.x, las.y][inside].mean(0)
        assert np.linalg.norm(centre - d["box"][:2]) < 0.5
    mesh = trimesh.load(out["ply"])
    assert mesh.vertices.dtype == np.float64 and mesh.vertices[:, 0].min() > 5e5
    lo, hi = mesh.bounds
    assert np.all(lo[:2] > UTM[:2]) and np.all(hi[:2] < UTM[:2] + 14.0)


def test_z_positive_rules(survey, results_dir, tmp_path, capsys, caplog):
    """A headerless positive-down file gets a warning naming --z-positive down; --z-positive down on
    elevations is an error naming the file and --z-positive up."""
    down = tmp_path / "down.xyz"
    write_points(down, PointCloud(survey[0] * [1, 1, -1]))
    common = ["--results", str(results_dir), "--classes", "reef_cone", "--crs", "EPSG:32610", "--method", "fixed"]
    plugin = tmp_path / "fixed_method.py"
    plugin.write_text(FIXED_METHOD)
    with caplog.at_level(logging.WARNING):
        assert main(["detect", "--input", str(down), "--out", str(tmp_path / "a.json"), "--plugins", str(plugin),
                     *common]) == 0
    assert "down.xyz" in caplog.text and "--z-positive down" in caplog.text
    elev = tmp_path / "elev.xyz"
    write_points(elev, PointCloud(survey[0]))
    assert main(["detect", "--input", str(elev), "--out", str(tmp_path / "b.json"), "--z-positive", "down",
                 "--plugins", str(plugin), *common]) == 2
    err = capsys.readouterr().err
    assert "elev.xyz" in err and "--z-positive up" in err and "Traceback" not in err


@pytest.mark.parametrize("case", ["projected-as-lonlat", "geotiff-without-crs", "coarse-geotiff", "lonlat-projected-crs"])
def test_bad_georeferencing_is_a_readable_error(survey, results_dir, tmp_path, capsys, case):
    xyz = survey[0]
    args = []
    if case == "projected-as-lonlat":  # UTM metres declared EPSG:4326: not longitude/latitude
        path = write_points(tmp_path / "utm.xyz", PointCloud(xyz))
        args, pattern = ["--crs", "EPSG:4326"], r"utm\.xyz: \d+ of \d+ soundings are not longitude/latitude.*--crs"
    elif case == "geotiff-without-crs":
        path = grid_geotiff(xyz, 0.2, tmp_path / "nocrs.tif", crs=None)
        pattern = r"nocrs\.tif: the raster carries no CRS.*--crs"
    elif case == "coarse-geotiff":
        path = grid_geotiff(xyz, 0.5, tmp_path / "coarse.tif")
        pattern = r"coarse\.tif: the grid's cells are 0\.5 m, coarser than 0\.25 m"
    else:
        path = lonlat_csv(xyz, tmp_path / "ll.csv")
        args, pattern = ["--crs", "EPSG:32610"], r"ll\.csv: the columns hold longitude/latitude but .* EPSG:32610"
    out = tmp_path / "o.json"
    assert main(["detect", "--input", str(path), "--out", str(out), "--results", str(results_dir), *args]) == 2
    err = capsys.readouterr().err
    assert re.search(pattern, err), err
    assert "Traceback" not in err and not out.exists()


def test_bag_is_read_as_elevations(survey, tmp_path):
    """A BAG (made from a GeoTIFF by GDAL's BAG driver) reads as the GeoTIFF does: nodes, nodata dropped,
    its CRS; an uncertainty band becomes an attribute."""
    import rasterio
    from rasterio.shutil import copy as rio_copy

    from sonardet.io.points import grid_cell_m, read_points

    tif = grid_geotiff(survey[0], 0.2, tmp_path / "g.tif", nodata=1e6)
    bag = tmp_path / "g.bag"
    try:
        rio_copy(tif, bag, driver="BAG")
    except rasterio.errors.RasterioError as exc:  # a GDAL built without BAG creation
        pytest.skip(f"GDAL cannot write BAG here: {exc}")
    from sonardet.io.crs import crs_string, horizontal_crs, parse_crs

    a, b = read_points(tif), read_points(bag)
    # A BAG's CRS is compound (horizontal + the survey's vertical datum, here unnamed): passed through whole.
    assert a.crs == crs_string(horizontal_crs(parse_crs(b.crs))) == "EPSG:32610"
    assert grid_cell_m(bag) == pytest.approx(0.2)
    assert len(b) == len(a)
    np.testing.assert_allclose(np.sort(b.xyz, axis=0), np.sort(a.xyz, axis=0), atol=1e-3)


@needs_real
def test_real_line_from_surveyors_files(results_dir, tmp_path):
    """The R2Sonic line as positive-down XYZ, as a lon/lat depth CSV and as a 0.2 m GeoTIFF: the same
    detections (none: it holds no objects) in EPSG:32610, and its soundings round-trip to the classified
    LAS (every one once, to the 1 mm of the LAS scale)."""
    real = pd.read_csv(REAL_FILE, sep=r"\s+", header=None).to_numpy(dtype=np.float64)
    down = tmp_path / "r2sonic_down.xyz.gz"
    write_points(down, PointCloud(real * [1, 1, -1]))
    inputs = {"down": ["--input", str(down), "--z-positive", "down", "--crs", "EPSG:32610",
                       "--las", str(tmp_path / "down.laz")],
              "lonlat": ["--input", str(lonlat_csv(real, tmp_path / "r2sonic_ll.csv"))],
              "tif": ["--input", str(grid_geotiff(real, 0.2, tmp_path / "r2sonic.tif"))]}
    docs = {}
    for name, args in inputs.items():
        assert main(["detect", *args, "--out", str(tmp_path / f"{name}.json"), "--results", str(results_dir),
                     "--quiet"]) == 0
        docs[name] = read_detections(tmp_path / f"{name}.json")
        assert docs[name]["crs"] == "EPSG:32610"
    assert docs["lonlat"]["input_crs"] == "EPSG:4326"
    counts = {k: len(d["detections"]) for k, d in docs.items()}
    assert counts == {"down": 0, "lonlat": 0, "tif": 0}, counts
    las = read_points(tmp_path / "down.laz")
    assert las.crs == "EPSG:32610" and len(las) == len(real)
    np.testing.assert_allclose(las.xyz, real, rtol=0, atol=0.0006)
    assert np.all(las.attributes["classification"] == 2) and np.all(las.attributes["object_id"] == -1)
