"""Tests of sonardet.io.annotations: scene and detection JSON round trips and validation errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sonardet import SCHEMA_VERSION
from sonardet.io.annotations import (
    AnnotationError,
    read_detections,
    read_scene,
    validate_scene,
    write_detections,
    write_scene,
)

CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]


def scene_doc(sid="scene_001"):
    return {
        "scene": sid,
        "seed": np.int64(42),
        "config_hash": "deadbeef",
        "extent": {"x_m": [0.0, 40.0], "y_m": [0.0, 30.0]},
        "objects": [
            {"id": 0, "cls": "tetrapod_b", "pose": {"t": np.array([1.0, 2.0, -11.0]), "q": [1.0, 0.0, 0.0, 0.0]},
             "box": np.array([1.0, 2.0, -10.5, 1.2, 1.1, 1.0, 0.3]), "n_points": 250, "visible": True},
            {"id": 1, "cls": "reef_ring", "pose": {"t": [5.0, 2.0, -11.0], "q": [0.0, 0.0, 0.0, 1.0]},
             "box": [5.0, 2.0, -10.6, 2.0, 2.0, 0.8, 0.0], "n_points": 0, "visible": False},
        ],
    }


def test_scene_round_trip(tmp_path):
    p = tmp_path / "scenes" / "scene_001.json"
    written = write_scene(p, scene_doc(), CLASSES)
    assert written["schema_version"] == SCHEMA_VERSION
    back = read_scene(p, CLASSES)
    assert back == written
    assert back["objects"][0]["box"] == [1.0, 2.0, -10.5, 1.2, 1.1, 1.0, 0.3]
    assert back["objects"][1]["visible"] is False and back["seed"] == 42
    assert [f.name for f in p.parent.iterdir()] == ["scene_001.json"]  # no temporary file left


def test_detections_round_trip(tmp_path):
    p = tmp_path / "detections" / "model_based" / "test" / "scene_001.json"
    dets = [{"cls": "tetrapod_s", "box": np.array([1, 2, -10, 1, 1, 1, -3.0]), "score": np.float32(0.5),
             "extras": {"fitness": 0.9}},
            {"cls": "reef_cone", "box": [4, 2, -10, 1, 1, 1, 0.0], "score": 1,
             "pose": {"t": [4, 2, -11], "q": [1, 0, 0, 0]}}]
    written = write_detections(p, "scene_001", "model_based", dets, CLASSES)
    back = read_detections(p, CLASSES)
    assert back == written
    assert back["detections"][1]["extras"] == {} and back["detections"][1]["score"] == 1.0
    assert back["method"] == "model_based" and json.loads(p.read_text())["schema_version"] == SCHEMA_VERSION


def test_rejects_unknown_schema_version_with_clear_message(tmp_path):
    p = tmp_path / "scene_001.json"
    doc = write_scene(p, scene_doc())
    doc["schema_version"] = 2
    p.write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"unknown schema_version 2; this sonardet reads and writes schema_version 1") as e:
        read_scene(p)
    assert str(p) in str(e.value)
    d = tmp_path / "scene_002.json"
    d.write_text(json.dumps({"scene": "scene_002", "method": "m", "detections": [], "schema_version": "1"}))
    with pytest.raises(ValueError, match="unknown schema_version '1'"):
        read_detections(d)


@pytest.mark.parametrize("mutate, pattern", [
    (lambda d: d["objects"][1].update(cls="boat"), r"objects\[1\]\.cls: unknown class 'boat'"),
    (lambda d: d["objects"][0].update(box=[1, 2, float("nan"), 1, 1, 1, 0]), r"objects\[0\]\.box: .*NaN"),
    (lambda d: d["objects"][0].update(box=[1, 2, 3, 1, 1, float("inf"), 0]), r"objects\[0\]\.box: .*NaN/Inf"),
    (lambda d: d["objects"][0].update(box=[1, 2, 3, -1, 1, 1, 0]), r"objects\[0\]\.box: .*>= 0"),
    (lambda d: d["objects"][0].update(box=[1, 2, 3]), r"objects\[0\]\.box: .*7 numbers"),
    (lambda d: d["objects"][1].pop("visible"), r"objects\[1\]: missing key\(s\) 'visible'"),
    (lambda d: d["objects"][1].update(visible="yes"), r"objects\[1\]\.visible"),
    (lambda d: d["objects"][1].update(id=0), r"objects\[1\]\.id: duplicate"),
    (lambda d: d["objects"][0]["pose"].update(q=[0, 0, 0, 0]), r"objects\[0\]\.pose\.q: .*non-zero"),
    (lambda d: d.pop("seed"), r"missing key\(s\) 'seed'"),
    (lambda d: d.update(scene="scene_999"), r"scene: scene id 'scene_999' does not match"),
])
def test_scene_validation_names_file_and_entry(tmp_path, mutate, pattern):
    p = tmp_path / "scene_001.json"
    doc = write_scene(p, scene_doc())
    mutate(doc)
    p.write_text(json.dumps(doc))
    with pytest.raises(AnnotationError, match=pattern) as e:
        read_scene(p, CLASSES)
    assert str(e.value).startswith(str(p))


def test_failed_write_keeps_the_old_file(tmp_path):
    p = tmp_path / "scene_001.json"
    write_scene(p, scene_doc())
    before = p.read_bytes()
    bad = scene_doc()
    bad["objects"][0]["box"] = [0, 0, 0, 1, 1, 1, float("nan")]
    with pytest.raises(ValueError):
        write_scene(p, bad)
    with pytest.raises(ValueError, match="does not match"):
        write_scene(tmp_path / "other.json", scene_doc())
    assert p.read_bytes() == before and sorted(f.name for f in tmp_path.iterdir()) == ["scene_001.json"]


def test_read_errors_for_missing_and_malformed_files(tmp_path):
    with pytest.raises(ValueError, match="file not found"):
        read_scene(tmp_path / "nope.json")
    p = tmp_path / "x.json"
    p.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        read_detections(p)


def test_in_memory_validation_without_filename_check():
    doc = validate_scene({**scene_doc("anything"), "schema_version": SCHEMA_VERSION}, "<memory>")
    assert doc["scene"] == "anything" and doc["objects"][0]["box"][6] == 0.3
