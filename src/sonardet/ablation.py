"""Speed-against-error ablation: one grid point = one detector setting run on a subset of test scenes.

A point is {name, method, params, fraction}: `method` is `model_based_ours`, `model_based_paper` or
`sasa`; `params` override that method's configured hyper-parameters; `fraction` (SASA only) is the
training-data fraction (%) it is trained on. `run_point` detects (training SASA first) on the given
scenes and returns the nuScenes metrics and the time per scene, so each grid point is one cached job
and adding a point reruns only that point. `reference_point` evaluates a main run's detection files on
the same scenes, so the default settings sit in the same plot at no extra cost.
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path

import numpy as np

from .eval.evaluate import evaluate
from .io.annotations import read_detections, read_scene

log = logging.getLogger("sonardet.ablation")

METHODS = ("model_based_ours", "model_based_paper", "sasa")


def check_points(points: list[dict], fractions) -> list[str]:
    """Problems of an ablation grid (names must be unique identifiers, methods known, SASA fractions
    among the configured training fractions); each names the point. Empty list = fine."""
    out, seen = [], set()
    for i, p in enumerate(points):
        where = f"ablation.points[{i}] ({p.get('name', '?')})"
        name = p.get("name", "")
        if not name.replace("_", "").replace("-", "").isalnum():
            out.append(f"{where}.name: use letters, digits, '_' or '-' only (it becomes a folder name)")
        if name in seen:
            out.append(f"{where}.name: {name!r} is used twice")
        seen.add(name)
        if p.get("method") not in METHODS:
            out.append(f"{where}.method: {p.get('method')!r} is not one of {list(METHODS)}")
        if p.get("method") == "sasa" and int(p.get("fraction", 100)) not in [int(f) for f in fractions]:
            out.append(f"{where}.fraction: {p.get('fraction')} is not one of split.fractions {list(fractions)}")
    return out


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


def _object_metas(objects_dir, classes) -> list[dict]:
    return [json.loads((Path(objects_dir) / f"{c}.json").read_text()) for c in classes]


def _evaluate(gt: dict, dets: dict, classes, evaluation: dict, objects_meta: list[dict]) -> dict:
    symmetric = [m["cls"] for m in objects_meta if m["rotationally_symmetric"]]
    periods = {m["cls"]: 2 * math.pi / m["symmetry_order"] for m in objects_meta if m["symmetry_order"] > 1}
    res = evaluate(gt, dets, classes, evaluation["dist_thresholds_m"], evaluation["headline_m"],
                   symmetric_classes=symmetric, min_recall=evaluation["min_recall"],
                   min_precision=evaluation["min_precision"], yaw_periods_rad=periods)
    head = repr(float(evaluation["headline_m"]))
    return {"mAP": float(res["mAP_headline"]),
            "AP": {c: float(res["per_class"][c]["AP"][head]) for c in classes},
            "n_pred": int(sum(res["per_class"][c]["n_pred"] for c in classes)),
            "n_gt": int(sum(res["per_class"][c]["n_gt"] for c in classes))}


def run_point(point: dict, scene_npzs: list[str], scene_jsons: list[str], base_params: dict, classes: list[str],
              evaluation: dict, objects_dir: str | Path, templates_dir: str | Path, work_dir: str | Path,
              train_npzs: list[str] | None = None, seed: int = 0, threads: int = 1) -> dict:
    """Run one ablation point on the scenes (`scene_npzs`, labels `scene_jsons` beside them).

    base_params: the method's configured hyper-parameters (model-based: the variant's overrides;
    SASA: the resolved preset with the config's overrides), updated with point['params'].
    Model-based: seconds_per_scene is the detector's wall time per scene (excluding file reads).
    SASA: the model is trained on `train_npzs` into work_dir/model (train_time_s reported) and
    seconds_per_scene is its inference time per scene. Returns {name, method, params, fraction,
    mAP, AP, n_pred, n_gt, seconds_per_scene, seconds_per_scene_max, train_time_s, n_scenes}.
    """
    from .objects import load_object

    method = point["method"]
    objects_dir, templates_dir, work_dir = Path(objects_dir), Path(templates_dir), Path(work_dir)
    metas = _object_metas(objects_dir, classes)
    gt = _ground_truth(scene_jsons)
    out = {"name": point["name"], "method": method, "params": point.get("params", {}),
           "fraction": point.get("fraction"), "n_scenes": len(scene_npzs), "train_time_s": None}
    if method.startswith("model_based_"):
        from .detect.model_based import ModelBasedDetector
        from .sim.scene import load_scene_points
        from .sim.templates import load_templates

        variant = method[len("model_based_"):]
        params = {**base_params, **point.get("params", {})}
        objects = {c: load_object(objects_dir / f"{c}.json") for c in classes}
        templates = {c: load_templates(templates_dir / f"{c}.npz") for c in classes}
        detector = ModelBasedDetector(templates, objects, params, variant)  # class models built once
        dets, secs = {}, []
        for i, p in enumerate(scene_npzs):
            sid = Path(p).stem
            xyz = load_scene_points(p)["xyz"]
            t0 = time.perf_counter()
            dets[sid], _ = detector(xyz)
            secs.append(time.perf_counter() - t0)
            log.info("%s: scene %s (%d/%d) %.1f s, %d detections", point["name"], sid, i + 1, len(scene_npzs),
                     secs[-1], len(dets[sid]))
    elif method == "sasa":
        from .detect.sasa import infer, train

        params = {**base_params, **point.get("params", {}), "seed": int(seed), "classes": list(classes),
                  "num_threads": int(threads), "progress": False}
        if not train_npzs:
            raise ValueError(f"ablation point {point['name']!r}: no training scenes for SASA")
        summary = train(train_npzs, [], params, work_dir / "model", resume=True)
        out["train_time_s"] = float(summary["train_time_s"])
        dets, timing = infer(work_dir / "model" / "model.pt", scene_npzs,
                             params={"num_threads": int(threads), "progress": False})
        secs = [float(timing["s_per_scene"])]  # mean inference time (model loaded once)
    else:
        raise ValueError(f"ablation point {point['name']!r}: unknown method {method!r}; use one of {METHODS}")
    out.update(_evaluate(gt, dets, classes, evaluation, metas))
    out["seconds_per_scene"] = float(np.mean(secs))
    out["seconds_per_scene_max"] = float(np.max(secs))
    return out


def reference_point(name: str, method: str, detection_jsons: list[str], scene_jsons: list[str],
                    seconds_per_scene: list[float], classes: list[str], evaluation: dict,
                    objects_dir: str | Path, fraction: int | None = None,
                    train_time_s: float | None = None) -> dict:
    """A main run's method (default settings) evaluated on the ablation scenes, in `run_point`'s format.

    seconds_per_scene: the method's time per scene on those scenes (model-based: detector seconds from
    its stats files; SASA: inference seconds per scene).
    """
    metas = _object_metas(objects_dir, classes)
    gt = _ground_truth(scene_jsons)
    dets = _detections(detection_jsons, classes)
    out = {"name": name, "method": method, "params": {}, "fraction": fraction, "n_scenes": len(detection_jsons),
           "train_time_s": train_time_s, "default": True}
    out.update(_evaluate(gt, dets, classes, evaluation, metas))
    out["seconds_per_scene"] = float(np.mean(seconds_per_scene))
    out["seconds_per_scene_max"] = float(np.max(seconds_per_scene))
    return out


def realism_effect_rows(methods: list[str], datasets: dict[str, tuple[str, list[str]]], scenes: list[str],
                        classes: list[str], evaluation: dict, objects_dir: str | Path,
                        detections_root: str | Path = "results/detections") -> list[dict]:
    """mAP of every method on every dataset of the one-at-a-time realism ablation, and its change
    against the plain scenes.

    datasets: effect name -> (dataset name, scene folder); must hold "none" (the plain synthetic
    scenes) and may hold "all" (every effect on). Detections are read from
    ``{detections_root}/{method}/{dataset}/{scene}.json``; ground truth from each dataset's own scene
    files (burial and visibility change with the effect). Returns one row per (effect, method) with
    mAP, AP per class, n_gt and delta_mAP = mAP - mAP on "none".
    """
    metas = _object_metas(objects_dir, classes)
    rows = []
    for effect, (dataset, folder) in datasets.items():
        gt = _ground_truth([Path(folder) / f"{s}.json" for s in scenes])
        for m in methods:
            dets = _detections([Path(detections_root) / m / dataset / f"{s}.json" for s in scenes], classes)
            r = _evaluate(gt, dets, classes, evaluation, metas)
            rows.append({"effect": effect, "dataset": dataset, "method": m, "n_scenes": len(scenes), **r})
    base = {r["method"]: r["mAP"] for r in rows if r["effect"] == "none"}
    for r in rows:
        r["delta_mAP"] = r["mAP"] - base[r["method"]]
    return rows
