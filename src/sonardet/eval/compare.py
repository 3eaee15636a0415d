"""Methods compared on one dataset, with uncertainty: mAP with a paired bootstrap interval, and each
method's paired difference to a reference method with its own interval, under three scorings:

* `all`: every box a method wrote (at most 500 per scene, the devkit's cap);
* `accepted`: only the boxes a method accepted as objects (`extras.accepted` true; methods that mark
  no box keep all of theirs), i.e. without a low-score tail of rejected hypotheses;
* `dont_care`: objects the study's simulator did not make (in piles or stacks, tumbled, or listed by
  id) are don't-care: not counted, and a box on one is neither true nor false positive.

The point values are those of :func:`sonardet.eval.evaluate` (the bootstrap's identity resample).
"""

from __future__ import annotations

import numpy as np

from ..geometry import quat_to_matrix
from ..io.artifacts import read_json_file
from .bootstrap import bootstrap_map, interval, scene_flags
from .evaluate import MAX_BOXES_PER_SCENE, evaluate, prepare

__all__ = ["PERTURBATION_BINS", "SCORINGS", "compare_files", "compare_methods", "mark_dont_care",
           "perturbation_breakdown"]

#: Bins of the model-mismatch breakdown: name -> (record key, [low, high) edges or values); an object
#: is in a bin if its perturbation record (or its burial_m) falls in it.
PERTURBATION_BINS = {
    "leg scale 0.65-0.85": ("leg_scale", (0.0, 0.85)),
    "leg scale 0.85-1.15": ("leg_scale", (0.85, 1.15)),
    "leg scale 1.15-1.35": ("leg_scale", (1.15, 9.0)),
    "broken leg": ("broken_leg", "set"),
    "legs intact": ("broken_leg", "unset"),
    "fouling 0-2 cm": ("fouling_m", (0.0, 0.02)),
    "fouling 2-5 cm": ("fouling_m", (0.02, 9.0)),
    "burial 0-0.1 m": ("burial_m", (0.0, 0.1)),
    "burial 0.1-0.2 m": ("burial_m", (0.1, 0.2)),
    "burial 0.2-0.3 m": ("burial_m", (0.2, 9.0)),
}

SCORINGS = ("all", "accepted", "dont_care")


def _tilt_deg(q, up_axes: np.ndarray) -> float:
    """Tilt (deg) of a pose q (w,x,y,z) from resting: the smallest angle of a class up axis to +z."""
    up = (quat_to_matrix(q) @ np.asarray(up_axes, dtype=np.float64).T)[2]
    return float(np.degrees(np.arccos(np.clip(up.max(), -1.0, 1.0))))


def mark_dont_care(gt: dict, rule: dict, up_axes: dict) -> dict:
    """A copy of the ground truth (scene -> objects) with `ignore` set on the don't-care objects of
    `rule`: {arrangements: names (e.g. pile, stack), tumbled_min_deg: tilt from resting above which an
    object is tumbled (None: off), ids: {scene: [object ids]}}. up_axes: class -> (K,3) up axes."""
    arr = set(rule.get("arrangements") or [])
    tilt_min = rule.get("tumbled_min_deg")
    ids = {s: set(v) for s, v in (rule.get("ids") or {}).items()}
    out = {}
    for sid, objs in gt.items():
        marked = []
        for o in objs:
            tumbled = tilt_min is not None and "pose" in o and _tilt_deg(o["pose"]["q"], up_axes[o["cls"]]) > tilt_min
            ignore = o.get("arrangement") in arr or tumbled or o.get("id") in ids.get(sid, ())
            marked.append({**o, "ignore": bool(ignore)})
        out[sid] = marked
    return out


def _accepted(dets: dict) -> dict:
    return {sid: [d for d in ds if (d.get("extras") or {}).get("accepted", True)] for sid, ds in dets.items()}


def _scored(gt, dets_by_method, classes, evaluation, eval_kwargs) -> tuple[dict, dict]:
    """evaluate() of every method, and its per-scene matching flags at the headline threshold."""
    results, flags = {}, {}
    for m, dets in dets_by_method.items():
        results[m] = evaluate(gt, dets, classes, evaluation["dist_thresholds_m"], evaluation["headline_m"],
                              min_recall=evaluation["min_recall"], min_precision=evaluation["min_precision"],
                              max_boxes_per_scene=evaluation.get("max_boxes_per_scene", MAX_BOXES_PER_SCENE),
                              **eval_kwargs)
        scenes, g, d, _, _ = prepare(gt, dets, classes, evaluation.get("max_boxes_per_scene", MAX_BOXES_PER_SCENE))
        flags[m] = scene_flags(g, d, classes, scenes, float(evaluation["headline_m"]))
    return results, flags


def _summary(results, samples, reference, level) -> dict:
    out = {}
    for m, res in results.items():
        lo, hi = interval(samples[m], level)
        row = {"mAP": float(res["mAP_headline"]), "low": lo, "high": hi,
               "AP": {c: float(v["AP"][repr(float(res["headline_m"]))]) for c, v in res["per_class"].items()},
               "n_pred": int(sum(v["n_pred"] for v in res["per_class"].values())),
               "n_gt": int(sum(v["n_gt"] for v in res["per_class"].values()))}
        if reference in samples and m != reference:
            d = samples[m] - samples[reference]
            dlo, dhi = interval(d, level)
            row["diff"] = {"vs": reference, "mAP": float(res["mAP_headline"] - results[reference]["mAP_headline"]),
                           "low": dlo, "high": dhi}
        out[m] = row
    return out


def compare_methods(gt: dict, dets_by_method: dict, classes, evaluation: dict, reference: str | None = None,
                    dont_care: dict | None = None, up_axes: dict | None = None, n_resamples: int = 1000,
                    seed: int = 0, level: float = 0.95, symmetric_classes=(), yaw_periods_rad=None) -> dict:
    """Every method (name -> scene -> detections) on the ground truth (scene -> objects), under each
    of SCORINGS ('dont_care' only with a rule). Returns {scorings: {name: {method: {mAP, low, high,
    AP (per class), n_pred, n_gt, diff {vs, mAP, low, high} (not for the reference)}}}, n_scenes,
    n_resamples, seed, level, reference}. The resamples (scenes drawn with replacement) are the same
    for every method and scoring (paired)."""
    kw = {"symmetric_classes": symmetric_classes, "yaw_periods_rad": yaw_periods_rad}
    variants = {"all": (gt, dets_by_method), "accepted": (gt, {m: _accepted(d) for m, d in dets_by_method.items()})}
    if dont_care is not None:
        variants["dont_care"] = (mark_dont_care(gt, dont_care, up_axes or {}), dets_by_method)
    out = {"n_scenes": len(gt), "n_resamples": int(n_resamples), "seed": int(seed), "level": float(level),
           "reference": reference, "dont_care_rule": dont_care, "scorings": {}}
    for name, (g, dets) in variants.items():
        results, flags = _scored(g, dets, classes, evaluation, kw)
        samples = bootstrap_map(flags, n_resamples, seed, evaluation["min_recall"], evaluation["min_precision"])
        out["scorings"][name] = _summary(results, samples, reference, level)
    return out


def _in_bin(obj: dict, key: str, rule) -> bool | None:
    """Whether an object is in a bin (None: the bin does not apply to it, e.g. leg scale of a cone)."""
    rec = {**(obj.get("perturbation") or {}), "burial_m": obj.get("burial_m", 0.0)}
    if key not in rec:
        return None
    v = rec[key]
    if rule == "set":
        return v is not None
    if rule == "unset":
        return v is None
    return v is not None and rule[0] <= float(v) < rule[1]


def perturbation_breakdown(gt: dict, dets_by_method: dict, classes, evaluation: dict) -> dict:
    """mAP per perturbation bin (:data:`PERTURBATION_BINS`) of every method on a model-mismatch set:
    the objects outside the bin are don't-care (a box on one is neither true nor false positive), and
    the mean is over the classes with objects in the bin. Returns {bin: {n_objects, classes,
    methods: {method: mAP}}}."""
    out = {}
    for name, (key, rule) in PERTURBATION_BINS.items():
        marked = {sid: [{**o, "ignore": not _in_bin(o, key, rule)} for o in objs] for sid, objs in gt.items()}
        counted = [o for objs in marked.values() for o in objs if not o["ignore"] and o.get("visible", True)]
        present = [c for c in classes if any(o["cls"] == c for o in counted)]
        if not present:
            continue
        row = {"n_objects": len(counted), "classes": present, "methods": {}}
        for m, dets in dets_by_method.items():
            res = evaluate(marked, dets, classes, [evaluation["headline_m"]], evaluation["headline_m"],
                           min_recall=evaluation["min_recall"], min_precision=evaluation["min_precision"],
                           max_boxes_per_scene=evaluation.get("max_boxes_per_scene", MAX_BOXES_PER_SCENE))
            hk = repr(float(evaluation["headline_m"]))
            row["methods"][m] = float(np.mean([res["per_class"][c]["AP"][hk] for c in present]))
        out[name] = row
    return out


def compare_files(scene_jsons, detections: dict, object_jsons, classes, evaluation: dict, reference: str | None,
                  dont_care: dict | None, n_resamples: int, seed: int, level: float) -> dict:
    """:func:`compare_methods` on files: scene JSONs (ground truth), method -> its detection JSONs on
    those scenes, the object JSONs (up axes of the don't-care rule, symmetry). Errors name the file."""
    import math

    from ..io.annotations import read_detections, read_scene

    gt = {}
    for p in scene_jsons:
        doc = read_scene(p, classes)
        gt[doc["scene"]] = doc["objects"]
    dets = {}
    for m, paths in detections.items():
        docs = [read_detections(p, classes) for p in paths]
        dets[m] = {d["scene"]: d["detections"] for d in docs}
    metas = [read_json_file(p, "object metadata file") for p in object_jsons]
    up = {m["cls"]: np.asarray(m["up_axes"], dtype=np.float64) for m in metas}
    sym = [m["cls"] for m in metas if m["rotationally_symmetric"]]
    periods = {m["cls"]: 2 * math.pi / m["symmetry_order"] for m in metas if m["symmetry_order"] > 1}
    out = compare_methods(gt, dets, classes, evaluation, reference=reference, dont_care=dont_care, up_axes=up,
                          n_resamples=n_resamples, seed=seed, level=level, symmetric_classes=sym,
                          yaw_periods_rad=periods)
    if any("perturbation" in o for objs in gt.values() for o in objs):
        out["perturbation_breakdown"] = perturbation_breakdown(gt, dets, classes, evaluation)
    return out
