"""nuScenes-style evaluation of 3D detections: AP at several centre-distance thresholds and TP errors.

`evaluate` works on in-memory ground truth and detections; `evaluate_files` reads the scene and
detection JSON files (sonardet.io.annotations), evaluates, and writes `metrics.json`, a per-class CSV
and the precision/recall curves. Semantics follow nuscenes-devkit 1.2.0 (`accumulate`, `calc_ap`,
`calc_tp`); see `matching` and `ap` for the details and tests/test_eval_devkit_peer.py for the check
against the devkit itself. Differences from the devkit's full pipeline (its `DetectionEval`), all on
purpose: no range filtering or max-boxes cap (predictions are never filtered), ground truth with
`visible == false` is removed before matching, scenes are pooled in sorted scene-id order, yaw is
read from the box instead of a quaternion, TP errors are None (not 1.0) for a class without any true
positive, and mAP is reported per threshold (the headline is the mean over classes of AP at
`headline_m`) as well as averaged over thresholds (the devkit's mAP).
"""

from __future__ import annotations

import csv
import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np

from .. import SCHEMA_VERSION
from ..io.annotations import check_box, check_class, read_detections, read_scene
from ..io.atomic import atomic_path, atomic_write_text
from .ap import (
    average_precision,
    first_recall_index,
    interpolated_pr,
    interpolated_tp_error,
    max_recall_index,
    recall_averaged_tp_error,
)
from .errors import center_error_m, size_error, yaw_error_rad
from .matching import match_class, pool_class

#: Names of the TP errors in the outputs: centre distance (m), 1 - aligned IoU (unitless), yaw (rad).
TP_ERROR_NAMES = ("centre_err_m", "size_err", "yaw_err_rad")


def threshold_key(dist_th_m: float) -> str:
    """The key under which a distance threshold (m) appears in the outputs, e.g. 0.5 -> '0.5', 2 -> '2.0'."""
    return repr(float(dist_th_m))


def _check_settings(classes, dist_thresholds_m, headline_m, min_recall, min_precision):
    classes = list(classes)
    if not classes or len(set(classes)) != len(classes) or not all(isinstance(c, str) and c for c in classes):
        raise ValueError(f"classes must be a non-empty list of distinct class names, got {classes!r}")
    ths = [float(t) for t in dist_thresholds_m]
    if not ths or len(set(ths)) != len(ths) or not all(math.isfinite(t) and t > 0 for t in ths):
        raise ValueError(f"dist_thresholds_m must be distinct positive finite distances (m), got {ths!r}")
    if float(headline_m) not in ths:
        raise ValueError(f"headline_m={headline_m} must be one of dist_thresholds_m={ths}")
    if not 0.0 <= min_precision < 1.0 or not 0.0 <= min_recall < 1.0:
        raise ValueError(f"need 0 <= min_recall < 1 and 0 <= min_precision < 1, got {min_recall}, {min_precision}")
    return classes, ths


#: The nuScenes devkit's limit of boxes per sample (`max_boxes_per_sample`).
MAX_BOXES_PER_SCENE = 500


def _cap(clean: list[dict], max_boxes: int | None) -> tuple[list[dict], int]:
    """The `max_boxes` best-scored detections of a scene (all classes together), in their file order;
    and how many were dropped. The devkit refuses a sample with more than 500 boxes; we keep the 500
    a compliant submission would keep, so extra low-score boxes cannot buy recall."""
    if max_boxes is None or len(clean) <= max_boxes:
        return clean, 0
    keep = np.sort(np.argsort([-d["score"] for d in clean], kind="stable")[:max_boxes])
    return [clean[i] for i in keep], len(clean) - max_boxes


def prepare(gt: dict, dets: dict, classes, max_boxes: int | None = MAX_BOXES_PER_SCENE):
    """Validate in-memory inputs; split visible/invisible ground truth; cap the detections per scene.
    Returns scenes, gt, dets, n_invisible, n_capped (detections dropped by the cap)."""
    scenes = sorted(gt)
    gt_visible, n_invisible = {}, {c: 0 for c in classes}
    for sid in scenes:
        kept = []
        for i, o in enumerate(gt[sid]):
            src = f"ground truth of scene {sid!r}"
            cls = check_class(o.get("cls"), classes, src, f"objects[{i}].cls")
            box = check_box(o.get("box"), src, f"objects[{i}].box")
            if o.get("visible", True):
                kept.append({"cls": cls, "box": box, "ignore": bool(o.get("ignore", False))})
            else:
                n_invisible[cls] += 1
        gt_visible[sid] = kept
    det_clean, n_capped = {}, 0
    for sid, items in dets.items():
        src = f"detections of scene {sid!r}"
        if sid not in gt:
            raise ValueError(f"{src}: scene {sid!r} is not among the {len(scenes)} ground-truth scenes; "
                             "evaluate detections only against the scenes they were run on")
        clean = []
        for i, d in enumerate(items):
            cls = check_class(d.get("cls"), classes, src, f"detections[{i}].cls")
            box = check_box(d.get("box"), src, f"detections[{i}].box")
            s = d.get("score")
            if isinstance(s, bool) or not isinstance(s, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(float(s)):
                raise ValueError(f"{src}: detections[{i}].score: score must be a finite number, got {s!r}")
            clean.append({"cls": cls, "box": box, "score": float(s)})
        det_clean[sid], dropped = _cap(clean, max_boxes)
        n_capped += dropped
    return scenes, gt_visible, det_clean, n_invisible, n_capped


def _tp_errors(pooled, match, conf, min_recall, yaw_scored, yaw_period_rad):
    """TP errors of one class at one threshold: devkit-style recall-averaged values and plain means."""
    ranks = np.nonzero(match.is_tp)[0]
    none = {k: None for k in TP_ERROR_NAMES}
    if len(ranks) == 0:
        return none, dict(none), False
    errs = {k: [] for k in TP_ERROR_NAMES}
    for r in ranks:
        p = pooled.pred_boxes[match.order[r]]
        g = pooled.gt_boxes[match.gt_scene[r]][match.gt_index[r]]
        errs["centre_err_m"].append(center_error_m(g, p))
        errs["size_err"].append(size_error(g, p))
        if yaw_scored:
            errs["yaw_err_rad"].append(yaw_error_rad(g[6], p[6], yaw_period_rad))
    scores = match.scores[ranks]
    averaged, plain = dict(none), dict(none)
    for k, v in errs.items():
        if not v:
            continue
        curve = interpolated_tp_error(np.asarray(v), scores, conf)
        averaged[k] = recall_averaged_tp_error(curve, conf, min_recall)
        plain[k] = float(np.mean(v))
    low_recall = max_recall_index(conf) < first_recall_index(min_recall)
    return averaged, plain, low_recall


def _yaw_periods(classes: list[str], yaw_periods_rad: dict | None) -> dict[str, float]:
    """class -> yaw period (rad): 2 pi unless `yaw_periods_rad` sets one in (0, 2 pi] (others ignored)."""
    periods = {c: 2.0 * math.pi for c in classes}
    for c, v in (yaw_periods_rad or {}).items():
        if c in periods:
            if not (math.isfinite(float(v)) and 0.0 < float(v) <= 2.0 * math.pi):
                raise ValueError(f"yaw_periods_rad[{c!r}] must be in (0, 2 pi], got {v!r}")
            periods[c] = float(v)
    return periods


def _evaluate_class(pooled, ths: list[float], headline_m: float, min_recall: float, min_precision: float,
                    yaw_scored: bool, yaw_period_rad: float, n_invisible: int) -> tuple[dict, dict]:
    """One class's entry of `per_class` and its PR curves {threshold_key: {recall, precision, confidence}}:
    AP and TP count per centre-distance threshold (m), TP errors at `headline_m`."""
    aps, n_tp, curves = {}, {}, {}
    tp_err = tp_plain = None
    low_recall, n_ignored = False, 0
    for th in ths:
        m = match_class(pooled, th)
        counted = ~m.is_ignored  # predictions on don't-care objects are neither TP nor FP
        rec, prec, conf = interpolated_pr(m.is_tp[counted], m.scores[counted], pooled.n_gt)
        key = threshold_key(th)
        aps[key] = average_precision(prec, min_recall, min_precision)
        n_tp[key] = m.n_tp
        curves[key] = {"recall": rec, "precision": prec, "confidence": conf}
        if th == headline_m:
            tp_err, tp_plain, low_recall = _tp_errors(pooled, m, conf, min_recall, yaw_scored, yaw_period_rad)
            n_ignored = int(m.is_ignored.sum())
    entry = {
        "AP": aps,
        "n_tp": n_tp,
        "n_pred": pooled.n_pred,
        "n_pred_dont_care": n_ignored,
        "n_gt": pooled.n_gt,
        "n_gt_invisible": n_invisible,
        "yaw_period_rad": yaw_period_rad if yaw_scored else None,
        "tp_errors": tp_err,
        "tp_errors_mean_over_matches": tp_plain,
        "tp_errors_low_recall": bool(low_recall),
        "yaw_scored": yaw_scored,
        "no_gt": pooled.n_gt == 0,
        "no_predictions": pooled.n_pred == 0,
        "no_tp": n_tp[threshold_key(headline_m)] == 0,
    }
    return entry, curves


def evaluate(gt: dict, dets: dict, classes, dist_thresholds_m, headline_m: float, symmetric_classes=(),
             min_recall: float = 0.1, min_precision: float = 0.1, yaw_periods_rad: dict | None = None,
             max_boxes_per_scene: int | None = MAX_BOXES_PER_SCENE) -> dict:
    """Evaluate detections against ground truth, nuScenes style. Returns a dict (see below).

    gt: scene id -> list of ground-truth objects {cls, box [x,y,z,l,w,h,yaw] (m, rad), visible (default
    True), ignore (default False: a don't-care object, see sonardet.eval.matching)}; objects with
    visible == False are removed before matching (and counted in n_gt_invisible).
    dets: scene id -> list of detections {cls, box, score}; a scene missing from `dets` has no
    detections; a scene with more than max_boxes_per_scene detections (the devkit's 500) keeps its
    best-scored ones (n_pred_capped counts the others; None: no cap). classes: class names to evaluate (others are an error). dist_thresholds_m:
    centre-distance match thresholds (m), e.g. (0.5, 1, 2, 4); headline_m: the one used for the headline
    mAP and the TP errors. symmetric_classes: classes whose yaw is not scored (names not in `classes`
    are ignored). min_recall / min_precision: as in the devkit (0.1 each). yaw_periods_rad: class ->
    angle (rad) after which its shape repeats, for n-fold symmetric classes (2 pi / 3 for a tetrapod;
    the devkit uses pi for barriers); default 2 pi.

    Returned keys: schema_version, classes, dist_thresholds_m, headline_m, min_recall, min_precision,
    symmetric_classes, n_scenes, mAP {threshold_key: mean over classes of AP}, mAP_headline,
    mAP_mean_over_thresholds, per_class {cls: {AP {th: float}, n_tp {th: int}, n_pred, n_gt,
    n_gt_invisible, yaw_period_rad, tp_errors {centre_err_m, size_err, yaw_err_rad} (recall-averaged as the devkit's
    calc_tp, None without any TP or for unscored yaw), tp_errors_mean_over_matches (plain means),
    tp_errors_low_recall (TPs exist but recall never exceeds min_recall, so tp_errors hold the devkit's
    1.0), yaw_scored, no_gt, no_predictions, no_tp}}, flags {no_gt, no_predictions, no_tp: class lists},
    and pr_curves {cls: {th: {recall, precision, confidence: (101,) arrays}}} (numpy; not JSON).
    A class with no ground truth or no predictions has AP 0 at every threshold and counts in the mAP.
    Scores should be > 0: as in the devkit, an interpolated confidence of exactly 0 marks recall the
    detector never reached, so TP errors of matches scored 0 fall outside the averaged range (and a
    class whose matches all score 0 gets the devkit's 1.0 with tp_errors_low_recall set).
    Raises ValueError for an unknown class, a non-finite box or score, or a detection scene id that is
    not in `gt`.
    """
    classes, ths = _check_settings(classes, dist_thresholds_m, headline_m, min_recall, min_precision)
    headline_m = float(headline_m)
    sym = [c for c in classes if c in set(symmetric_classes)]
    periods = _yaw_periods(classes, yaw_periods_rad)
    scenes, gt_vis, det_clean, n_invisible, n_capped = prepare(gt, dets, classes, max_boxes_per_scene)

    per_class, pr_curves = {}, {}
    for cls in classes:
        pooled = pool_class(gt_vis, det_clean, cls, scenes)
        per_class[cls], pr_curves[cls] = _evaluate_class(pooled, ths, headline_m, min_recall, min_precision,
                                                         cls not in sym, periods[cls], n_invisible[cls])

    m_ap = {threshold_key(t): float(np.mean([per_class[c]["AP"][threshold_key(t)] for c in classes])) for t in ths}
    return {
        "schema_version": SCHEMA_VERSION,
        "classes": classes,
        "dist_thresholds_m": ths,
        "headline_m": headline_m,
        "min_recall": float(min_recall),
        "min_precision": float(min_precision),
        "symmetric_classes": sym,
        "n_scenes": len(scenes),
        "max_boxes_per_scene": max_boxes_per_scene,
        "n_pred_capped": int(n_capped),
        "mAP": m_ap,
        "mAP_headline": m_ap[threshold_key(headline_m)],
        "mAP_mean_over_thresholds": float(np.mean(list(m_ap.values()))),
        "per_class": per_class,
        "flags": {
            "no_gt": [c for c in classes if per_class[c]["no_gt"]],
            "no_predictions": [c for c in classes if per_class[c]["no_predictions"]],
            "no_tp": [c for c in classes if per_class[c]["no_tp"]],
        },
        "pr_curves": pr_curves,
    }


def metrics_for_json(result: dict) -> dict:
    """The JSON part of an `evaluate` result (everything except the numpy PR curves)."""
    return {k: v for k, v in result.items() if k != "pr_curves"}


def per_class_rows(result: dict) -> list[dict]:
    """One flat row per class (for the CSV): counts, AP per threshold, headline TP errors, flags."""
    rows = []
    hk = threshold_key(result["headline_m"])
    for cls in result["classes"]:
        pc = result["per_class"][cls]
        row = {"cls": cls, "n_gt": pc["n_gt"], "n_gt_invisible": pc["n_gt_invisible"], "n_pred": pc["n_pred"]}
        for t in result["dist_thresholds_m"]:
            row[f"AP@{threshold_key(t)}m"] = pc["AP"][threshold_key(t)]
        row[f"n_tp@{hk}m"] = pc["n_tp"][hk]
        for k in TP_ERROR_NAMES:
            row[k] = pc["tp_errors"][k]
        row.update(tp_errors_low_recall=pc["tp_errors_low_recall"], no_gt=pc["no_gt"],
                   no_predictions=pc["no_predictions"], no_tp=pc["no_tp"])
        rows.append(row)
    return rows


def _csv_text(rows: list[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if v is None else repr(v) if isinstance(v, float) else v) for k, v in r.items()})
    return buf.getvalue()


def write_per_class_csv(path, result: dict) -> None:
    """Write the per-class table (see `per_class_rows`) atomically as CSV; empty cells mean None."""
    atomic_write_text(path, _csv_text(per_class_rows(result)))


def pr_curve_arrays(result: dict) -> dict[str, np.ndarray]:
    """PR curves as arrays: classes (C,), thresholds_m (T,), recall (101,), precision and confidence (C,T,101)."""
    classes, ths = result["classes"], result["dist_thresholds_m"]
    pc = result["pr_curves"]
    get = lambda name: np.array([[pc[c][threshold_key(t)][name] for t in ths] for c in classes])  # noqa: E731
    return {
        "classes": np.array(classes),
        "thresholds_m": np.array(ths, dtype=np.float64),
        "recall": np.asarray(pc[classes[0]][threshold_key(ths[0])]["recall"]),
        "precision": get("precision"),
        "confidence": get("confidence"),
    }


def write_pr_curves(path, result: dict) -> None:
    """Write the PR curves atomically: `.npz` (arrays of `pr_curve_arrays`, byte-deterministic) or `.csv`
    (long format: cls, threshold_m, recall, precision, confidence)."""
    path = Path(path)
    arrays = pr_curve_arrays(result)
    if path.suffix == ".csv":
        lines = ["cls,threshold_m,recall,precision,confidence"]
        for i, c in enumerate(arrays["classes"]):
            for j, t in enumerate(arrays["thresholds_m"]):
                for r, p, f in zip(arrays["recall"], arrays["precision"][i, j], arrays["confidence"][i, j]):
                    lines.append(f"{c},{float(t)!r},{float(r)!r},{float(p)!r},{float(f)!r}")
        atomic_write_text(path, "\n".join(lines) + "\n")
        return
    if path.suffix != ".npz":
        raise ValueError(f"{path}: PR curves are written as .npz or .csv, not {path.suffix!r}")
    with atomic_path(path) as tmp:
        # A zip with fixed timestamps instead of np.savez, so the same input gives the same bytes.
        with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED) as zf:
            for name, arr in arrays.items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asarray(arr), allow_pickle=False)
                zf.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), buf.getvalue())


def evaluate_files(scene_json_paths, detection_json_paths, out_metrics_json, out_per_class_csv, out_pr_curves,
                   classes, dist_thresholds_m, headline_m: float, symmetric_classes=(),
                   min_recall: float = 0.1, min_precision: float = 0.1, allow_missing_detections: bool = False,
                   dataset: str | None = None, yaw_periods_rad: dict | None = None,
                   max_boxes_per_scene: int | None = MAX_BOXES_PER_SCENE) -> dict:
    """Read scene and detection JSON files, evaluate (see `evaluate`) and write the three outputs.

    scene_json_paths: `results/scenes/{scene}.json` files (ground truth; invisible objects dropped);
    detection_json_paths: `results/detections/{method}/{dataset}/{scene}.json` files, at most one per
    scene. Every file is validated (sonardet.io.annotations); errors are ValueErrors naming the file and
    the entry: unknown schema_version, unknown class, NaN/Inf box or score, missing keys, scene id not
    matching the file name, a detection file whose scene is not among the scene files, two files for one
    scene, and (unless allow_missing_detections) a scene without a detection file.
    Outputs, written atomically only after everything is computed: out_metrics_json (the JSON part of
    the result plus method, dataset), out_per_class_csv, out_pr_curves (.npz or .csv). Returns the result.
    """
    gt, methods = {}, set()
    for p in scene_json_paths:
        doc = read_scene(p, classes)
        if doc["scene"] in gt:
            raise ValueError(f"{p}: scene {doc['scene']!r} appears in more than one scene file")
        gt[doc["scene"]] = doc["objects"]
    dets, det_src = {}, {}
    for p in detection_json_paths:
        doc = read_detections(p, classes)
        sid = doc["scene"]
        if sid not in gt:
            raise ValueError(f"{p}: scene: detections for scene {sid!r}, which is not among the {len(gt)} "
                             "ground-truth scene files given; pass the matching scenes/{scene}.json")
        if sid in dets:
            raise ValueError(f"{p}: scene: a second detection file for scene {sid!r} (first: {det_src[sid]})")
        dets[sid], det_src[sid] = doc["detections"], p
        methods.add(doc["method"])
    missing = sorted(set(gt) - set(dets))
    if missing and not allow_missing_detections:
        raise ValueError(f"no detection file for {len(missing)} scene(s): {', '.join(missing[:10])}"
                         f"{' ...' if len(missing) > 10 else ''}; every evaluated scene needs one (an empty "
                         "'detections' list when nothing was found)")
    result = evaluate(gt, dets, classes, dist_thresholds_m, headline_m, symmetric_classes, min_recall, min_precision,
                      yaw_periods_rad, max_boxes_per_scene)
    metrics = metrics_for_json(result)
    metrics = {"schema_version": metrics.pop("schema_version"),
               "method": sorted(methods)[0] if len(methods) == 1 else sorted(methods),
               "dataset": dataset, "scenes_without_detections": missing, **metrics}
    text = json.dumps(metrics, indent=1, allow_nan=False) + "\n"
    write_pr_curves(out_pr_curves, result)
    write_per_class_csv(out_per_class_csv, result)
    atomic_write_text(out_metrics_json, text)
    return result
