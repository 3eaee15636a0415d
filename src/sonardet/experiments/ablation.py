"""Speed-against-error ablation: one grid point = one detector setting run on the ablation scenes.

A point is {name, method, params, fraction}: `method` names a configured method (e.g.
`model_based_ours`) or a method family (e.g. `sasa`, then `fraction` picks the training split);
`params` override that method's configured parameters. `run_point` detects (training first, for a
trained method) on the given scenes and returns the nuScenes metrics and the time per scene, so each
grid point is one cached job and adding a point reruns only that point. `reference_point` evaluates
a main run's detection files on the same scenes, so the default settings sit in the same plot at no
extra cost. `realism_effect_rows` scores the methods of the one-at-a-time realism ablation.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from .. import methods
from ..eval.evaluate import evaluate
from ..io.annotations import read_detections, read_scene
from ..io.artifacts import read_json_file
from ..io.scenes import read_scene_points
from ..methods import Method, Resources

log = logging.getLogger("sonardet.experiments.ablation")


def _family_names() -> set[str]:
    return {f.name for f in methods.families()}


def check_points(points: list[dict], config: dict) -> list[str]:
    """Problems of an ablation grid (names must be unique identifiers; the method a configured method
    or a family; a trained family's fraction among split.fractions); each names the point."""
    out, seen = [], set()
    fractions = [int(f) for f in config["split"]["fractions"]]
    for i, p in enumerate(points):
        where = f"ablation.points[{i}] ({p.get('name', '?')})"
        name = p.get("name", "")
        if not name.replace("_", "").replace("-", "").isalnum():
            out.append(f"{where}.name: use letters, digits, '_' or '-' only (it becomes a folder name)")
        if name in seen:
            out.append(f"{where}.name: {name!r} is used twice")
        seen.add(name)
        method = p.get("method")
        if method not in _family_names():
            try:
                methods.get(method, config)
            except ValueError:
                out.append(f"{where}.method: {method!r} is neither a method nor a method family "
                           f"({sorted(_family_names())})")
                continue
        m = point_method(p, config)
        if m.trained and int(m.fraction) not in fractions:
            out.append(f"{where}.fraction: {p.get('fraction')} is not one of split.fractions {fractions}")
    return out


def point_method(point: dict, config: dict) -> Method:
    """The Method a grid point runs: its family's method with the point's params on top."""
    name = point["method"]
    family = name if name in _family_names() else methods.get(name, config).family
    return methods.family(family).ablation_method(point, config)


def _ground_truth(scene_jsons) -> dict:
    gt = {}
    for p in scene_jsons:
        doc = read_scene(p)
        gt[doc["scene"]] = doc["objects"]
    return gt


def _detections(detection_jsons, classes) -> dict:
    """scene id -> detections of each detection file."""
    out = {}
    for p in detection_jsons:
        doc = read_detections(p, classes)
        out[doc["scene"]] = doc["detections"]
    return out


def _evaluate(gt: dict, dets: dict, classes, evaluation: dict, object_jsons) -> dict:
    metas = [read_json_file(p, "object metadata file") for p in object_jsons]
    metas = [m for m in metas if m["cls"] in classes]
    symmetric = [m["cls"] for m in metas if m["rotationally_symmetric"]]
    periods = {m["cls"]: 2 * math.pi / m["symmetry_order"] for m in metas if m["symmetry_order"] > 1}
    res = evaluate(gt, dets, classes, evaluation["dist_thresholds_m"], evaluation["headline_m"],
                   symmetric_classes=symmetric, min_recall=evaluation["min_recall"],
                   min_precision=evaluation["min_precision"], yaw_periods_rad=periods,
                   max_boxes_per_scene=evaluation.get("max_boxes_per_scene", 500))
    head = repr(float(evaluation["headline_m"]))
    return {"mAP": float(res["mAP_headline"]),
            "AP": {c: float(res["per_class"][c]["AP"][head]) for c in classes},
            "n_pred": int(sum(res["per_class"][c]["n_pred"] for c in classes)),
            "n_gt": int(sum(res["per_class"][c]["n_gt"] for c in classes))}


def _detect_scenes(method: Method, resources: Resources, scene_npzs, name: str) -> tuple[dict, list[float]]:
    """Detections per scene and seconds per scene (per-dataset methods: their mean inference time)."""
    family = methods.family(method.family)
    if method.runner == "per_dataset":
        dets, timing = family.detect_dataset(method, resources, scene_npzs)
        return dets, [float(timing["s_per_scene"])]
    detector = family.load(method, resources)
    dets, secs = {}, []
    for i, p in enumerate(scene_npzs):
        sid = Path(p).stem
        xyz = read_scene_points(p)["xyz"]
        t0 = time.perf_counter()
        dets[sid], _ = detector(xyz)
        secs.append(time.perf_counter() - t0)
        log.info("%s: scene %s (%d/%d) %.1f s, %d detections", name, sid, i + 1, len(scene_npzs), secs[-1],
                 len(dets[sid]))
    return dets, secs


def run_point(point: dict, method: Method, scene_npzs: list[str], scene_jsons: list[str], classes: list[str],
              evaluation: dict, object_jsons: list[str], resources: Resources, work_dir: str | Path,
              train_npzs: list[str] | None = None, other_sets: dict | None = None) -> dict:
    """Run one ablation point's method (see :func:`point_method`) on the scenes (`scene_npzs`,
    labels `scene_jsons`).

    A trained method is first trained on `train_npzs` into work_dir/model (train_time_s reported).
    seconds_per_scene: per-scene methods, the detector's wall time per scene (file reads excluded);
    per-dataset methods, their mean inference time per scene. Returns {name, method, params,
    fraction, n_scenes, train_time_s, mAP, AP, n_pred, n_gt, seconds_per_scene, seconds_per_scene_max},
    plus, with `other_sets` (set name -> (scene npzs, scene jsons), e.g. the mismatch dev set), the
    same model's {mAP, AP, n_pred, n_gt, n_scenes} on each under "other_sets".
    """
    work_dir = Path(work_dir)
    out = {"name": point["name"], "method": point["method"], "params": point.get("params", {}),
           "fraction": point.get("fraction"), "n_scenes": len(scene_npzs), "train_time_s": None}
    if method.trained:
        if not train_npzs:
            raise ValueError(f"ablation point {point['name']!r}: no training scenes for {method.name}")
        summary = methods.family(method.family).train(method, train_npzs, [], work_dir / "model", resources)
        out["train_time_s"] = float(summary["train_time_s"])
        resources = replace(resources, model_path=work_dir / "model" / "model.pt")
    dets, secs = _detect_scenes(method, resources, scene_npzs, point["name"])
    out.update(_evaluate(_ground_truth(scene_jsons), dets, classes, evaluation, object_jsons))
    out["seconds_per_scene"] = float(np.mean(secs))
    out["seconds_per_scene_max"] = float(np.max(secs))
    for set_name, (npzs, jsons) in (other_sets or {}).items():
        dets, _ = _detect_scenes(method, resources, npzs, f"{point['name']} on {set_name}")
        out.setdefault("other_sets", {})[set_name] = {
            **_evaluate(_ground_truth(jsons), dets, classes, evaluation, object_jsons), "n_scenes": len(npzs)}
    return out


def reference_point(method: Method, detection_jsons: list[str], scene_jsons: list[str],
                    seconds_per_scene: list[float], classes: list[str], evaluation: dict, object_jsons: list[str],
                    train_time_s: float | None = None) -> dict:
    """A main run's method (default settings) evaluated on the ablation scenes, in `run_point`'s format:
    named '{method} (default)', its `method` the family for trained methods (as their grid points
    name it) and the method otherwise.

    seconds_per_scene: the method's time per scene on those scenes (per-scene methods: detector seconds
    from its stats files; per-dataset methods: inference seconds per scene).
    """
    out = {"name": f"{method.name} (default)", "method": method.family if method.trained else method.name,
           "params": {}, "fraction": method.fraction, "n_scenes": len(detection_jsons),
           "train_time_s": train_time_s, "default": True}
    out.update(_evaluate(_ground_truth(scene_jsons), _detections(detection_jsons, classes), classes, evaluation,
                         object_jsons))
    out["seconds_per_scene"] = float(np.mean(seconds_per_scene))
    out["seconds_per_scene_max"] = float(np.max(seconds_per_scene))
    return out


def realism_effect_rows(effects: dict, classes: list[str], evaluation: dict, object_jsons: list[str]) -> list[dict]:
    """mAP of every method on every dataset of the one-at-a-time realism ablation, and its change
    against the plain scenes.

    effects: effect name -> {"dataset": name, "scenes": scene JSON paths, "detections": {method:
    detection JSON paths (same scenes, same order)}, "keys": the effect's config keys}; must hold
    "none" (the plain synthetic scenes) and may hold "all" (every effect on). Ground truth comes from
    each dataset's own scene files (burial and visibility change with the effect). Returns one row per
    (effect, method) with mAP, AP per class, n_gt, delta_mAP = mAP - mAP on "none" and keys.
    """
    rows = []
    for effect, spec in effects.items():
        gt = _ground_truth(spec["scenes"])
        for m, paths in spec["detections"].items():
            r = _evaluate(gt, _detections(paths, classes), classes, evaluation, object_jsons)
            rows.append({"effect": effect, "dataset": spec["dataset"], "method": m, "n_scenes": len(paths), **r})
    base = {r["method"]: r["mAP"] for r in rows if r["effect"] == "none"}
    for r in rows:
        r["delta_mAP"] = r["mAP"] - base[r["method"]]
    keys = {e: list(spec.get("keys", [])) for e, spec in effects.items()}
    for r in rows:
        r["keys"] = keys[r["effect"]]
    return rows
