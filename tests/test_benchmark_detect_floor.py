"""The floor benchmark's object sweep helpers (benchmarks/detect_floor.py): the AP of a scene over
the classes it holds, and the --object-counts flag's checks."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from detect_floor import parse_counts, present_map

from sonardet.eval.evaluate import evaluate

CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]


def _obj(cls, x, y, score=None):
    o = {"cls": cls, "box": [x, y, -11.0, 2.0, 2.0, 1.0, 0.0]}
    return o | ({"score": score} if score is not None else {})


def test_present_map_averages_only_the_classes_in_the_scene():
    gt = {"n0002": [_obj("reef_cone", 0, 0), _obj("reef_cone", 10, 0)]}
    hit = {"n0002": [_obj("reef_cone", 0.1, 0, 0.9), _obj("reef_cone", 10, 0.1, 0.8)]}
    res = evaluate(gt, hit, CLASSES, [0.5, 1.0], 0.5)
    assert res["mAP_headline"] == pytest.approx(0.25)  # absent classes count as AP 0 in the metric
    assert present_map(res) == pytest.approx(1.0)
    half = {"n0002": [_obj("reef_cone", 0.1, 0, 0.9), _obj("tetrapod_s", 10, 0.1, 0.8)]}
    assert 0.0 < present_map(evaluate(gt, half, CLASSES, [0.5, 1.0], 0.5)) < 1.0


def test_object_counts_flag():
    assert parse_counts("100,1, 25,25") == [1, 25, 100]
    assert parse_counts(None) == []
    with pytest.raises(SystemExit, match="counts >= 1"):
        parse_counts("0,25")
    with pytest.raises(SystemExit, match="comma-separated integers"):
        parse_counts("a,b")
