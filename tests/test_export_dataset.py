"""`sonardet export-dataset --format openpcdet`: the synthetic scenes and splits in OpenPCDet's custom-dataset
layout, read back and checked against the scene JSON (boxes, classes, points in float32 local frame)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import yaml
from test_sasa_model import CLASSES, make_scene

from sonardet.cli import main
from sonardet.io.annotations import read_scene
from sonardet.io.openpcdet import export_openpcdet, read_openpcdet_labels
from sonardet.io.scenes import read_scene_points


@pytest.fixture
def results(tmp_path):
    """A results folder with five small scenes (UTM-sized coordinates) and their splits."""
    scenes = tmp_path / "results" / "scenes"
    scenes.mkdir(parents=True)
    for i in range(5):
        make_scene(scenes, f"s{i:04d}", i, CLASSES)
    splits = tmp_path / "results" / "splits"
    splits.mkdir()
    for name, ids in (("train", ["s0000", "s0001"]), ("test", ["s0002"]), ("dev", ["s0003", "s0004"]),
                      ("train_50", ["s0001"])):
        (splits / f"{name}.txt").write_text("\n".join(ids) + "\n")
    return tmp_path / "results"


def test_openpcdet_layout_read_back(results, tmp_path, capsys):
    out = tmp_path / "custom"
    assert main(["export-dataset", "--format", "openpcdet", "--results", str(results), "--out", str(out),
                 "--quiet"]) == 0
    assert "5 scenes" in capsys.readouterr().out
    sets = {p.stem: p.read_text().split() for p in (out / "ImageSets").glob("*.txt")}
    assert sets == {"train": ["s0000", "s0001"], "val": ["s0003", "s0004"], "test": ["s0002"], "train_50": ["s0001"]}
    info = json.loads((out / "sonardet_dataset.json").read_text())
    assert info["split_names"]["dev"] == "val"
    for sid in [f"s{i:04d}" for i in range(5)]:
        pts = np.load(out / "points" / f"{sid}.npy")
        scene = read_scene_points(results / "scenes" / f"{sid}.npz")
        origin = np.asarray(info["origins"][sid])
        assert pts.dtype == np.float32 and pts.shape == (len(scene["xyz"]), 4)
        np.testing.assert_allclose(pts[:, :3], scene["xyz"] - origin, atol=2e-5)
        assert np.all(pts[:, 3] == 0.0)
        doc = read_scene(results / "scenes" / f"{sid}.json")
        labels = read_openpcdet_labels(out / "labels" / f"{sid}.txt")
        truth = [o for o in doc["objects"] if o["visible"]]
        assert [c for _, c in labels] == [o["cls"] for o in truth]
        for (box, _), o in zip(labels, truth):
            np.testing.assert_allclose(np.add(box[:3], origin), o["box"][:3], rtol=0, atol=1e-9)
            assert box[3:6] == o["box"][3:6] and -math.pi <= box[6] < math.pi
            assert math.isclose(math.cos(box[6]), math.cos(o["box"][6]), abs_tol=1e-12)
    cfg = yaml.safe_load((out / "custom_dataset.yaml").read_text())
    assert cfg["CLASS_NAMES"] == list(json.loads((out / "sonardet_dataset.json").read_text())["classes"])
    lo, hi = np.array(cfg["POINT_CLOUD_RANGE"][:3]), np.array(cfg["POINT_CLOUD_RANGE"][3:])
    assert np.allclose(((hi - lo)[:2] / 0.1) % 16, 0) and np.isclose((hi - lo)[2] / 0.15, 40)


def test_export_refuses_missing_scenes_and_features(results, tmp_path, capsys):
    with pytest.raises(ValueError, match="feature must be one of"):
        export_openpcdet(results / "scenes", {"train": ["s0000"]}, tmp_path / "o", classes=CLASSES, feature="rgb")
    with pytest.raises(ValueError, match="scene files missing for s0099"):
        export_openpcdet(results / "scenes", {"train": ["s0099"]}, tmp_path / "o", classes=CLASSES)
    with pytest.raises(ValueError, match="no 'beam' array for --feature beam"):
        export_openpcdet(results / "scenes", {"train": ["s0000"]}, tmp_path / "o", classes=CLASSES, feature="beam")
    assert main(["export-dataset", "--results", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]) == 2
    assert "train.txt: missing" in capsys.readouterr().err


def test_progress_bars_are_quiet_off_a_terminal_and_with_quiet(capsys):
    """The long steps' bars (sonardet.progress) draw only on a terminal and never with --quiet."""
    from sonardet.progress import progress_bar

    bar = progress_bar(range(3), desc="export", enabled=True)  # pytest's stderr is not a terminal
    assert list(bar) == [0, 1, 2] and bar.disable
    assert progress_bar(range(3), enabled=False).disable
    assert capsys.readouterr().err == ""
