"""The classified soundings of a survey: the indexed box search equals a scan of every sounding per box."""

from __future__ import annotations

import numpy as np

from sonardet.geometry import points_in_box
from sonardet.survey import classify_soundings
from sonardet.survey.outputs import BOX_MARGIN_M, CLASS_OBJECT, CLASS_SEABED


def _scan_every_sounding(xyz, dets, classes, margin_m=BOX_MARGIN_M):
    """Reference: every box tests every sounding (in descending score; the first box to claim wins)."""
    n = len(xyz)
    cls_idx = {c: i for i, c in enumerate(classes)}
    out = {"classification": np.full(n, CLASS_SEABED, np.uint8), "object_id": np.full(n, -1, np.int32),
           "cls": np.full(n, -1, np.int16)}
    for k in sorted(range(len(dets)), key=lambda i: -float(dets[i]["score"])):
        box = np.asarray(dets[k]["box"], dtype=np.float64)
        free = np.flatnonzero(out["object_id"] < 0)
        inside = free[points_in_box(xyz[free], box, margin_m)]
        out["classification"][inside] = CLASS_OBJECT
        out["object_id"][inside] = k
        out["cls"][inside] = cls_idx.get(str(dets[k]["cls"]), -1)
    return out


def test_indexed_search_equals_full_scan_on_overlapping_boxes():
    rng = np.random.default_rng(3)
    origin = np.array([550_000.0, 4_180_000.0, -11.5])  # UTM-sized coordinates: rounding matters
    xyz = origin + np.c_[rng.uniform(0, 30, (60_000, 2)), rng.normal(0, 0.8, 60_000)]
    classes = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
    dets = []
    for k in range(40):  # boxes overlapping one another, some rotated, some on the survey's edge
        c = origin[:2] + rng.uniform(-1, 31, 2)
        dets.append({"cls": classes[k % 4] if k != 7 else "not_a_class", "score": float(rng.random()),
                     "box": [float(c[0]), float(c[1]), float(origin[2] + rng.uniform(-0.5, 0.5)),
                             float(rng.uniform(1, 3)), float(rng.uniform(1, 3)), float(rng.uniform(0.7, 2.1)),
                             float(rng.uniform(-np.pi, np.pi))]})
    # soundings exactly on a box's face (axis-aligned box: its grown face is the search square's edge)
    dets.append({"cls": "reef_cone", "score": 0.5, "box": [origin[0] + 10.0, origin[1] + 10.0, origin[2], 2.0, 2.0,
                                                             1.4, 0.0]})
    edge = origin + [10.0 + 1.0 + BOX_MARGIN_M, 10.0, 0.0]
    xyz = np.vstack([xyz, edge, edge - [2 * (1.0 + BOX_MARGIN_M), 0, 0]])
    got = classify_soundings(xyz, dets, classes)
    want = _scan_every_sounding(xyz, dets, classes)
    for key in want:
        assert got[key].dtype == want[key].dtype
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)
    assert (got["object_id"] >= 0).sum() > 1000  # the boxes hold soundings: the check compares something
    assert (got["cls"][got["object_id"] == 7] == -1).all() and (got["object_id"] == 7).any()


def test_no_detections_or_no_soundings():
    xyz = np.zeros((5, 3))
    f = classify_soundings(xyz, [], ["reef_ring"])
    assert (f["classification"] == CLASS_SEABED).all() and (f["object_id"] == -1).all()
    f = classify_soundings(np.zeros((0, 3)), [{"cls": "reef_ring", "score": 1.0, "box": [0, 0, 0, 1, 1, 1, 0]}],
                           ["reef_ring"])
    assert len(f["object_id"]) == 0
