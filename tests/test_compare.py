"""Uncertainty and scorings of the comparison (sonardet.eval.bootstrap, sonardet.eval.compare) and the
evaluation's devkit cap and don't-care objects (sonardet.eval.evaluate / matching)."""

from __future__ import annotations

import numpy as np
import pytest

from sonardet.eval import evaluate
from sonardet.eval.bootstrap import bootstrap_map, interval, scene_flags
from sonardet.eval.compare import compare_methods, mark_dont_care
from sonardet.eval.evaluate import prepare

CLASSES = ["a", "b"]
EV = {"dist_thresholds_m": [0.5, 1.0], "headline_m": 0.5, "min_recall": 0.1, "min_precision": 0.1}


def _case(seed: int, n_scenes: int = 12, noise_m: float = 0.3, fp: int = 3):
    """Ground truth and a noisy detector's output on random scenes (boxes 1 m, scores in (0, 1))."""
    rng = np.random.default_rng(seed)
    gt, dets = {}, {}
    for s in range(n_scenes):
        sid = f"s{s:04d}"
        objs = [{"id": i, "cls": CLASSES[i % 2], "box": [*rng.uniform(0, 30, 2), 0.0, 1.0, 1.0, 1.0, 0.0],
                 "visible": True, "pose": {"t": [0, 0, 0], "q": [1.0, 0, 0, 0]}, "arrangement": "scatter"}
                for i in range(int(rng.integers(3, 8)))]
        ds = [{"cls": o["cls"], "box": [o["box"][0] + rng.normal(0, noise_m), o["box"][1] + rng.normal(0, noise_m),
                                        0.0, 1.0, 1.0, 1.0, 0.0], "score": float(rng.uniform(0.2, 1.0))}
              for o in objs if rng.random() < 0.9]
        ds += [{"cls": CLASSES[k % 2], "box": [*rng.uniform(0, 30, 2), 0.0, 1.0, 1.0, 1.0, 0.0],
                "score": float(rng.uniform(0.0, 0.6))} for k in range(fp)]
        gt[sid], dets[sid] = objs, ds
    return gt, dets


def _flags(gt, dets):
    scenes, g, d, _, _ = prepare(gt, dets, CLASSES)
    return scene_flags(g, d, CLASSES, scenes, 0.5)


def test_identity_resample_is_the_evaluation():
    for seed in range(5):
        gt, dets = _case(seed)
        res = evaluate(gt, dets, CLASSES, [0.5], 0.5)
        f = _flags(gt, dets)
        assert f.map(np.ones(len(gt), dtype=np.int64), 0.1, 0.1) == pytest.approx(res["mAP_headline"], abs=1e-12)
        # A scene drawn twice counts twice: the same as evaluating a copy of it.
        counts = np.ones(len(gt), dtype=np.int64)
        counts[0] = 2
        gt2, dets2 = dict(gt), dict(dets)
        gt2["zcopy"], dets2["zcopy"] = gt["s0000"], dets["s0000"]
        res2 = evaluate(gt2, dets2, CLASSES, [0.5], 0.5)
        assert f.map(counts, 0.1, 0.1) == pytest.approx(res2["mAP_headline"], abs=1e-12)


def test_bootstrap_is_seeded_paired_and_brackets_the_estimate():
    gt, dets_a = _case(1)
    _, dets_b = _case(1, noise_m=0.2)  # same truth, a slightly better detector
    flags = {"a": _flags(gt, dets_a), "b": _flags(gt, dets_b)}
    s1 = bootstrap_map(flags, 300, seed=4)
    assert np.array_equal(s1["a"], bootstrap_map(flags, 300, seed=4)["a"])
    assert not np.array_equal(s1["a"], bootstrap_map(flags, 300, seed=5)["a"])
    lo, hi = interval(s1["a"])
    point = evaluate(gt, dets_a, CLASSES, [0.5], 0.5)["mAP_headline"]
    assert lo <= point <= hi and hi - lo > 0
    # Paired: the difference varies less than either method over the resamples.
    assert np.std(s1["b"] - s1["a"]) < min(np.std(s1["a"]), np.std(s1["b"]))


def test_devkit_cap_keeps_the_best_500_per_scene():
    gt = {"s": [{"cls": "a", "box": [0, 0, 0, 1, 1, 1, 0], "visible": True}]}
    dets = {"s": [{"cls": "a", "box": [50.0 + i, 0, 0, 1, 1, 1, 0], "score": 0.5} for i in range(600)]
            + [{"cls": "a", "box": [0.1, 0, 0, 1, 1, 1, 0], "score": 0.01}]}
    capped = evaluate(gt, dets, ["a"], [0.5], 0.5)
    assert capped["n_pred_capped"] == 101 and capped["per_class"]["a"]["n_tp"]["0.5"] == 0  # the TP was cut
    assert capped["per_class"]["a"]["n_pred"] == 500
    free = evaluate(gt, dets, ["a"], [0.5], 0.5, max_boxes_per_scene=None)
    assert free["per_class"]["a"]["n_tp"]["0.5"] == 1 and free["n_pred_capped"] == 0


def test_dont_care_objects_are_neither_counted_nor_punished():
    box = [0, 0, 0, 1, 1, 1, 0]
    gt = {"s": [{"cls": "a", "box": box, "visible": True},
                {"cls": "a", "box": [5, 0, 0, 1, 1, 1, 0], "visible": True, "ignore": True}]}
    dets = {"s": [{"cls": "a", "box": box, "score": 0.9},
                  {"cls": "a", "box": [5.1, 0, 0, 1, 1, 1, 0], "score": 0.95},  # on the don't-care object
                  {"cls": "a", "box": [5.2, 0, 0, 1, 1, 1, 0], "score": 0.8}]}  # a second one on it
    res = evaluate(gt, dets, ["a"], [0.5], 0.5)
    pc = res["per_class"]["a"]
    assert pc["n_gt"] == 1 and pc["n_pred_dont_care"] == 2 and res["mAP_headline"] == pytest.approx(1.0)
    plain = {"s": [{**o, "ignore": False} for o in gt["s"]]}
    assert evaluate(plain, dets, ["a"], [0.5], 0.5)["per_class"]["a"]["n_gt"] == 2
    # A box of another class on a don't-care object is still a false positive.
    dets["s"].append({"cls": "b", "box": [5.0, 0, 0, 1, 1, 1, 0], "score": 0.99})
    gt["s"].append({"cls": "b", "box": [20, 0, 0, 1, 1, 1, 0], "visible": True})
    assert evaluate(gt, dets, ["a", "b"], [0.5], 0.5)["per_class"]["b"]["AP"]["0.5"] < 0.6


def test_mark_dont_care_by_arrangement_tilt_and_id():
    half = np.sqrt(0.5)
    gt = {"s": [{"id": 0, "cls": "a", "arrangement": "pile", "pose": {"q": [1, 0, 0, 0]}, "box": [0] * 7},
                {"id": 1, "cls": "a", "arrangement": "scatter", "pose": {"q": [half, half, 0, 0]}, "box": [0] * 7},
                {"id": 2, "cls": "a", "arrangement": "scatter", "pose": {"q": [1, 0, 0, 0]}, "box": [0] * 7},
                {"id": 3, "cls": "a", "arrangement": "scatter", "pose": {"q": [1, 0, 0, 0]}, "box": [0] * 7}]}
    up = {"a": np.array([[0.0, 0.0, 1.0]])}
    marked = mark_dont_care(gt, {"arrangements": ["pile"], "tumbled_min_deg": 30, "ids": {"s": [3]}}, up)
    assert [o["ignore"] for o in marked["s"]] == [True, True, False, True]
    # An object whose other axis points up (a cube on its side) is not tumbled.
    up_cube = {"a": np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, -1.0, 0.0]])}
    assert not mark_dont_care(gt, {"tumbled_min_deg": 30}, up_cube)["s"][1]["ignore"]


def test_compare_methods_scorings_and_paired_differences():
    gt, dets = _case(3)
    tail = {sid: [{**d, "extras": {"accepted": d["score"] > 0.2}} for d in ds] for sid, ds in dets.items()}
    _, better = _case(3, noise_m=0.1)
    out = compare_methods(gt, {"ref": better, "m": tail}, CLASSES, EV, reference="ref",
                          dont_care={"ids": {"s0000": [0, 1]}}, up_axes={c: np.eye(3)[2:] for c in CLASSES},
                          n_resamples=200, seed=1)
    assert set(out["scorings"]) == {"all", "accepted", "dont_care"}
    m = out["scorings"]["all"]["m"]
    assert m["low"] <= m["mAP"] <= m["high"] and m["diff"]["vs"] == "ref"
    assert m["diff"]["low"] <= m["diff"]["mAP"] <= m["diff"]["high"]
    assert "diff" not in out["scorings"]["all"]["ref"]
    assert out["scorings"]["accepted"]["m"]["n_pred"] < m["n_pred"]
    assert out["scorings"]["dont_care"]["m"]["n_gt"] == m["n_gt"] - 2
    assert out["scorings"]["all"]["m"]["mAP"] == pytest.approx(
        evaluate(gt, tail, CLASSES, [0.5, 1.0], 0.5)["mAP_headline"], abs=1e-12)
