"""Tests of sonardet.eval: matching, AP, TP errors, evaluate() and evaluate_files().

The bit-exact comparison with the official devkit is in test_eval_devkit_peer.py; these tests pin
properties (order invariance, perfect detector, a low-scored far false positive never helps), hand-
computed values and the error handling.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sonardet import SCHEMA_VERSION
from sonardet.eval import (
    average_precision,
    center_distance_matrix,
    evaluate,
    evaluate_files,
    ranking_order,
    scale_iou,
    size_error,
    threshold_key,
    yaw_error_rad,
)
from sonardet.io.annotations import write_detections, write_scene

CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
SYMMETRIC = ["reef_ring", "reef_cone"]
THS = [0.5, 1.0, 2.0, 4.0]
KEYS = [threshold_key(t) for t in THS]


def box(x, y, l=1.0, w=1.0, h=1.0, yaw=0.0, z=-10.0):
    return [float(x), float(y), z, l, w, h, yaw]


def run(gt, dets, headline=0.5, classes=CLASSES, ths=THS):
    return evaluate(gt, dets, classes, ths, headline, SYMMETRIC)


def aps(res):
    return {c: res["per_class"][c]["AP"] for c in res["classes"]}


# -------------------------------------------------------------------------------- hypothesis strategies
xy = st.tuples(st.integers(-40, 40), st.integers(-40, 40)).map(lambda p: (p[0] * 0.25, p[1] * 0.25))
gt_obj = st.builds(lambda c, p, v: {"cls": c, "box": box(*p), "visible": v},
                   st.sampled_from(CLASSES), xy, st.sampled_from([True, True, True, False]))
det_obj = st.builds(lambda c, p, s: {"cls": c, "box": box(*p), "score": s},
                    st.sampled_from(CLASSES), xy, st.sampled_from([0.1, 0.3, 0.5, 0.7, 0.9]))


@st.composite
def scenes(draw, distinct_scores=False):
    ids = draw(st.lists(st.text("abcxyz", min_size=1, max_size=3), min_size=1, max_size=4, unique=True))
    gt = {s: draw(st.lists(gt_obj, max_size=6)) for s in ids}
    dets = {}
    for s in ids:
        items = draw(st.lists(det_obj, max_size=8))
        # near-GT predictions make matches likely
        for o in gt[s]:
            if draw(st.booleans()):
                dx, dy = draw(xy.map(lambda p: (p[0] / 10, p[1] / 10)))
                items.append({"cls": o["cls"], "box": box(o["box"][0] + dx, o["box"][1] + dy),
                              "score": draw(st.sampled_from([0.2, 0.4, 0.6, 0.8]))})
        dets[s] = items
    if distinct_scores:
        n = sum(len(v) for v in dets.values())
        scores = draw(st.permutations(list(range(1, n + 1))))
        it = iter(scores)
        for v in dets.values():
            for d in v:
                d["score"] = next(it) / (n + 1)
    return gt, dets


@settings(max_examples=60, deadline=None)
@given(scenes(), st.randoms(use_true_random=False))
def test_ap_invariant_to_scene_order(case, rnd):
    gt, dets = case
    order = list(gt)
    rnd.shuffle(order)
    gt2 = {s: gt[s] for s in order}
    dets2 = {s: dets[s] for s in reversed(order)}
    assert aps(run(gt, dets)) == aps(run(gt2, dets2))


@settings(max_examples=60, deadline=None)
@given(scenes(distinct_scores=True), st.randoms(use_true_random=False))
def test_ap_invariant_to_prediction_order_with_distinct_scores(case, rnd):
    gt, dets = case
    shuffled = {}
    for s in gt:
        items = list(dets[s])
        rnd.shuffle(items)
        shuffled[s] = items
    r1, r2 = run(gt, dets), run(gt, shuffled)
    assert aps(r1) == aps(r2)
    assert {c: r1["per_class"][c]["tp_errors"] for c in CLASSES} == {c: r2["per_class"][c]["tp_errors"] for c in CLASSES}


@settings(max_examples=60, deadline=None)
@given(scenes(), st.randoms(use_true_random=False))
def test_perfect_detector_scores_one(case, rnd):
    gt, _ = case
    dets = {s: [{"cls": o["cls"], "box": list(o["box"]), "score": 0.01 + rnd.random()}
                for o in objs if o["visible"]]
            for s, objs in gt.items()}
    res = run(gt, dets)
    for c in CLASSES:
        pc = res["per_class"][c]
        for k in KEYS:
            if pc["n_gt"]:
                assert abs(pc["AP"][k] - 1.0) <= 1e-9
                assert pc["tp_errors"]["centre_err_m"] == 0.0 and pc["tp_errors"]["size_err"] == 0.0
            else:
                assert pc["AP"][k] == 0.0 and pc["no_gt"] and c in res["flags"]["no_gt"]


@settings(max_examples=60, deadline=None)
@given(scenes(), st.sampled_from(CLASSES))
def test_far_lowest_scored_false_positive_never_raises_ap(case, cls):
    gt, dets = case
    before = run(gt, dets)
    lowest = min([d["score"] for v in dets.values() for d in v], default=1.0)
    scene = sorted(gt)[0]
    dets2 = {s: list(v) for s, v in dets.items()}
    dets2[scene] = dets2[scene] + [{"cls": cls, "box": box(1000.0, 1000.0), "score": lowest / 2}]
    after = run(gt, dets2)
    for c in CLASSES:
        for k in KEYS:
            assert after["per_class"][c]["AP"][k] <= before["per_class"][c]["AP"][k]


# ------------------------------------------------------------------------------------ hand-made cases
def test_hand_computed_ap_one_of_two_found():
    # recall reaches 0.5 with precision 1: grid points 11..50 score 0.9, 51..100 score 0 -> 40*0.9/90/0.9
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0)}, {"cls": "tetrapod_b", "box": box(10, 0)}]}
    dets = {"s": [{"cls": "tetrapod_b", "box": box(0.1, 0), "score": 0.9}]}
    res = run(gt, dets)
    assert res["per_class"]["tetrapod_b"]["AP"]["0.5"] == pytest.approx(4 / 9, abs=1e-12)
    assert res["mAP"]["0.5"] == pytest.approx(4 / 9 / 4, abs=1e-12)
    assert res["mAP_headline"] == res["mAP"]["0.5"]


def test_average_precision_clips_low_precision():
    assert average_precision(np.full(101, 0.1)) == 0.0
    assert average_precision(np.ones(101)) == pytest.approx(1.0, abs=1e-15)


def test_ties_rank_later_prediction_first_like_the_devkit():
    s = [0.5, 0.5, 0.7, 0.5]
    devkit = [i for (v, i) in sorted((v, i) for (i, v) in enumerate(s))][::-1]
    assert ranking_order(s).tolist() == devkit == [2, 3, 1, 0]


def test_prediction_exactly_at_threshold_is_not_a_match():
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0)}]}
    dets = {"s": [{"cls": "tetrapod_b", "box": box(0.5, 0), "score": 0.9}]}
    pc = run(gt, dets)["per_class"]["tetrapod_b"]
    assert pc["AP"]["0.5"] == 0.0 and pc["n_tp"]["0.5"] == 0 and pc["AP"]["1.0"] > 0.99
    assert pc["no_tp"] and pc["tp_errors"]["centre_err_m"] is None


def test_distance_matrix_matches_linalg_norm_bitwise():
    rng = np.random.default_rng(3)
    p, g = rng.uniform(-50, 50, (40, 2)), rng.uniform(-50, 50, (30, 2))
    ref = np.array([[np.linalg.norm(np.array(a) - np.array(b)) for b in g] for a in p])
    assert np.array_equal(center_distance_matrix(p, g), ref)


def test_tp_errors_single_match():
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0, 2, 1, 1, yaw=3.1)},
                {"cls": "reef_ring", "box": box(5, 5, 2, 2, 1, yaw=0.0)}]}
    dets = {"s": [{"cls": "tetrapod_b", "box": box(0.3, 0.4, 1, 1, 1, yaw=-3.1), "score": 0.8},
                  {"cls": "reef_ring", "box": box(5, 5.1, 2, 2, 1, yaw=2.0), "score": 0.8}]}
    res = run(gt, dets, headline=1.0)
    e = res["per_class"]["tetrapod_b"]["tp_errors"]
    assert e["centre_err_m"] == pytest.approx(0.5, abs=1e-12)
    assert e["size_err"] == pytest.approx(0.5, abs=1e-12)  # volumes 2 and 1, intersection 1
    assert e["yaw_err_rad"] == pytest.approx(2 * math.pi - 6.2, abs=1e-12)  # wraps through +-pi
    ring = res["per_class"]["reef_ring"]
    assert ring["tp_errors"]["yaw_err_rad"] is None and not ring["yaw_scored"]  # symmetric: not scored
    assert ring["tp_errors"]["centre_err_m"] == pytest.approx(0.1, abs=1e-12)
    assert ring["tp_errors_mean_over_matches"]["centre_err_m"] == pytest.approx(0.1, abs=1e-12)
    assert res["symmetric_classes"] == SYMMETRIC


def test_yaw_error_of_n_fold_symmetric_class_uses_its_period():
    period = 2 * math.pi / 3  # tetrapods look the same after a third of a turn
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0, yaw=0.1)}]}
    dets = {"s": [{"cls": "tetrapod_b", "box": box(0, 0, yaw=0.1 + period + 0.05), "score": 0.5}]}
    res = evaluate(gt, dets, CLASSES, THS, 0.5, SYMMETRIC, yaw_periods_rad={"tetrapod_b": period})
    assert res["per_class"]["tetrapod_b"]["tp_errors"]["yaw_err_rad"] == pytest.approx(0.05, abs=1e-12)
    assert res["per_class"]["tetrapod_b"]["yaw_period_rad"] == period
    assert run(gt, dets)["per_class"]["tetrapod_b"]["tp_errors"]["yaw_err_rad"] == pytest.approx(period + 0.05)


def test_tp_errors_low_recall_follow_devkit_convention():
    # one TP of 20 objects: recall 0.05 never passes min_recall, so the devkit's calc_tp gives 1.0
    gt = {"s": [{"cls": "tetrapod_s", "box": box(3 * i, 0)} for i in range(20)]}
    dets = {"s": [{"cls": "tetrapod_s", "box": box(0.2, 0), "score": 0.5}]}
    pc = run(gt, dets)["per_class"]["tetrapod_s"]
    assert pc["tp_errors_low_recall"] and pc["tp_errors"]["centre_err_m"] == 1.0
    assert pc["tp_errors_mean_over_matches"]["centre_err_m"] == pytest.approx(0.2, abs=1e-12)


def test_error_functions():
    assert scale_iou(box(0, 0, 2, 2, 2), box(9, 9, 1, 1, 1, yaw=1.0)) == pytest.approx(1 / 8)
    assert size_error(box(0, 0, 1, 2, 3), box(0, 0, 1, 2, 3)) == 0.0
    assert size_error(box(0, 0, 1, 1, 0), box(0, 0, 1, 1, 0)) == 0.0  # degenerate, identical
    for a, b in [(0.0, math.pi), (-3.0, 3.0), (1.0, 1.0 + 4 * math.pi), (math.pi, -math.pi)]:
        e = yaw_error_rad(a, b)
        assert 0.0 <= e <= math.pi
        assert e == pytest.approx(abs((a - b + math.pi) % (2 * math.pi) - math.pi), abs=1e-12)


def test_invisible_ground_truth_is_removed_before_matching():
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0), "visible": True},
                {"cls": "tetrapod_b", "box": box(10, 0), "visible": False}]}
    dets = {"s": [{"cls": "tetrapod_b", "box": box(0, 0), "score": 0.9}]}
    pc = run(gt, dets)["per_class"]["tetrapod_b"]
    assert pc["AP"]["0.5"] == pytest.approx(1.0) and pc["n_gt"] == 1 and pc["n_gt_invisible"] == 1
    # a prediction on the invisible object is a false positive (predictions are never filtered)
    dets["s"].append({"cls": "tetrapod_b", "box": box(10, 0), "score": 0.95})
    assert run(gt, dets)["per_class"]["tetrapod_b"]["AP"]["0.5"] < 0.9


def test_zero_gt_and_zero_prediction_classes_score_zero_and_are_flagged():
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0)}, {"cls": "reef_cone", "box": box(5, 0)}]}
    dets = {"s": [{"cls": "tetrapod_b", "box": box(0, 0), "score": 0.9},
                  {"cls": "tetrapod_s", "box": box(9, 0), "score": 0.9}]}
    res = run(gt, dets)
    pc = res["per_class"]
    assert pc["tetrapod_s"]["no_gt"] and not pc["tetrapod_s"]["no_predictions"]
    assert pc["reef_cone"]["no_predictions"] and not pc["reef_cone"]["no_gt"]
    assert pc["reef_ring"]["no_gt"] and pc["reef_ring"]["no_predictions"]
    for c in ("tetrapod_s", "reef_cone", "reef_ring"):
        assert all(v == 0.0 for v in pc[c]["AP"].values())
        assert pc[c]["tp_errors"] == {"centre_err_m": None, "size_err": None, "yaw_err_rad": None}
    assert res["flags"]["no_gt"] == ["reef_ring", "tetrapod_s"]
    assert res["flags"]["no_predictions"] == ["reef_ring", "reef_cone"]
    assert res["mAP_headline"] == pytest.approx(0.25)  # zero-AP classes count in the mean


def test_in_memory_bad_inputs():
    gt = {"s": [{"cls": "tetrapod_b", "box": box(0, 0)}]}
    with pytest.raises(ValueError, match=r"scene 'nope'.*not among"):
        run(gt, {"nope": []})
    with pytest.raises(ValueError, match=r"detections\[0\]\.score"):
        run(gt, {"s": [{"cls": "tetrapod_b", "box": box(0, 0), "score": float("nan")}]})
    with pytest.raises(ValueError, match=r"objects\[0\]\.cls.*unknown class 'boat'"):
        run({"s": [{"cls": "boat", "box": box(0, 0)}]}, {})
    with pytest.raises(ValueError, match="headline_m"):
        run(gt, {}, headline=3.0)


# --------------------------------------------------------------------------------------- file level
def _scene(tmp_path, sid, objects):
    objs = [{"id": i, "cls": o["cls"], "pose": {"t": o["box"][:3], "q": [1.0, 0, 0, 0]}, "box": o["box"],
             "n_points": 10, "visible": o.get("visible", True)} for i, o in enumerate(objects)]
    p = tmp_path / "scenes" / f"{sid}.json"
    write_scene(p, {"scene": sid, "seed": 1, "config_hash": "abc", "extent": [0, 10, 0, 10], "objects": objs})
    return p


def _dets(tmp_path, sid, dets):
    p = tmp_path / "detections" / "mb" / "test" / f"{sid}.json"
    write_detections(p, sid, "mb", dets)
    return p


def _files_case(tmp_path):
    s1 = _scene(tmp_path, "s1", [{"cls": "tetrapod_b", "box": box(0, 0)},
                                 {"cls": "reef_ring", "box": box(5, 0), "visible": False}])
    s2 = _scene(tmp_path, "s2", [{"cls": "tetrapod_s", "box": box(1, 1)}])
    d1 = _dets(tmp_path, "s1", [{"cls": "tetrapod_b", "box": box(0.2, 0), "score": 0.7}])
    d2 = _dets(tmp_path, "s2", [{"cls": "tetrapod_s", "box": box(1, 1.3), "score": 0.6},
                                {"cls": "tetrapod_s", "box": box(7, 1.3), "score": 0.65}])
    return [s1, s2], [d1, d2]


def _evaluate_files(tmp_path, scenes, dets, out="out", pr="pr.npz"):
    o = tmp_path / out
    return evaluate_files(scenes, dets, o / "metrics.json", o / "per_class.csv", o / pr,
                          CLASSES, THS, 0.5, SYMMETRIC, dataset="test")


def test_evaluate_files_writes_outputs_deterministically(tmp_path):
    scenes, dets = _files_case(tmp_path)
    res = _evaluate_files(tmp_path, scenes, dets, "a")
    _evaluate_files(tmp_path, scenes[::-1], dets[::-1], "b")
    for name in ("metrics.json", "per_class.csv", "pr.npz"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes(), name
    m = json.loads((tmp_path / "a" / "metrics.json").read_text())
    assert m["schema_version"] == SCHEMA_VERSION and m["method"] == "mb" and m["dataset"] == "test"
    assert m["mAP_headline"] == res["mAP_headline"] and set(m["mAP"]) == set(KEYS)
    assert m["per_class"]["reef_ring"]["n_gt_invisible"] == 1 and m["per_class"]["reef_ring"]["no_gt"]
    assert m["per_class"]["tetrapod_b"]["AP"]["0.5"] == pytest.approx(1.0)
    csv_lines = (tmp_path / "a" / "per_class.csv").read_text().splitlines()
    assert csv_lines[0].startswith("cls,n_gt,n_gt_invisible,n_pred,AP@0.5m") and len(csv_lines) == 5
    with np.load(tmp_path / "a" / "pr.npz") as z:
        assert z["precision"].shape == (4, 4, 101) and z["recall"].shape == (101,)
        assert z["classes"].tolist() == CLASSES and z["thresholds_m"].tolist() == THS
    _evaluate_files(tmp_path, scenes, dets, "c", pr="pr.csv")
    assert len((tmp_path / "c" / "pr.csv").read_text().splitlines()) == 1 + 4 * 4 * 101
    assert not list(tmp_path.glob("**/.*"))  # no temporary files left behind


def _bad_det_file(tmp_path, sid, det):
    p = tmp_path / "bad" / f"{sid}.json"
    p.parent.mkdir(exist_ok=True)
    good = {"cls": "tetrapod_b", "box": box(0, 0), "score": 0.5, "extras": {}}
    p.write_text(json.dumps({"schema_version": 1, "scene": sid, "method": "mb", "detections": [good, det]}))
    return p


@pytest.mark.parametrize("det, pattern", [
    ({"cls": "boat", "box": box(0, 0), "score": 0.5}, r"detections\[1\]\.cls: unknown class 'boat'"),
    ({"cls": "tetrapod_b", "box": box(float("nan"), 0), "score": 0.5}, r"detections\[1\]\.box: .*NaN"),
    ({"cls": "tetrapod_b", "box": box(0, 0), "score": float("nan")}, r"detections\[1\]\.score"),
    ({"cls": "tetrapod_b", "box": box(0, 0)}, r"detections\[1\]: missing key\(s\) 'score'"),
])
def test_evaluate_files_rejects_bad_detections_naming_file_and_entry(tmp_path, det, pattern):
    scenes, dets = _files_case(tmp_path)
    bad = _bad_det_file(tmp_path, "s1", det)
    with pytest.raises(ValueError, match=pattern) as e:
        _evaluate_files(tmp_path, scenes, [bad, dets[1]])
    assert str(bad) in str(e.value)
    assert not (tmp_path / "out").exists()  # nothing half-written


def test_evaluate_files_rejects_unknown_scene_and_missing_or_duplicate_files(tmp_path):
    scenes, dets = _files_case(tmp_path)
    other = _dets(tmp_path, "s9", [])
    with pytest.raises(ValueError, match=r"s9\.json: scene: .*'s9'.*not among") as e:
        _evaluate_files(tmp_path, scenes, dets + [other])
    assert str(other) in str(e.value)
    with pytest.raises(ValueError, match=r"no detection file for 1 scene\(s\): s2"):
        _evaluate_files(tmp_path, scenes, dets[:1])
    dup = tmp_path / "dup" / "s1.json"
    dup.parent.mkdir()
    dup.write_bytes(dets[0].read_bytes())
    with pytest.raises(ValueError, match="second detection file"):
        _evaluate_files(tmp_path, scenes, dets + [dup])
