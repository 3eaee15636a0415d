"""Run the official nuscenes-devkit `accumulate` / `calc_ap` / `calc_tp` on cases read as JSON from stdin.

Runs inside the devkit's own virtualenv (numpy<2; see tests/test_eval_devkit_peer.py), so it imports
nothing from sonardet. Input (stdin)::

    {"cases": [{"classes": [...], "thresholds": [...], "tp_threshold": <float>, "min_recall": <float>,
                "min_precision": <float>, "scenes": [scene ids, in pooling order],
                "barrier_class": <class or null>,
                "gt": {scene: [{"cls", "box": [x,y,z,l,w,h,yaw]}]},
                "dets": {scene: [{"cls", "box", "score"}]}}, ...]}

Output (stdout)::

    {"devkit_version": str, "numpy_version": str,
     "results": [{cls: {"ap": [per threshold], "precision": [[101] per threshold],
                        "confidence": [[101] per threshold], "tp": {"trans_err", "scale_err", "orient_err"},
                        "has_match": bool}}]}

Our classes are mapped, in order, onto devkit class names whose evaluation has no special case (not
'barrier', whose yaw period is pi, nor 'traffic_cone'), except that the optional case key
"barrier_class" maps that one class onto 'barrier' to check a yaw period of pi. Scenes are added to the EvalBoxes in the given
order, since the devkit pools predictions in insertion order.
"""

import json
import math
import sys
from importlib.metadata import version

import numpy as np
from nuscenes.eval.common.data_classes import EvalBoxes
from nuscenes.eval.common.utils import center_distance
from nuscenes.eval.detection.algo import accumulate, calc_ap, calc_tp
from nuscenes.eval.detection.data_classes import DetectionBox

DEVKIT_NAMES = ["car", "truck", "bus", "trailer", "construction_vehicle", "pedestrian", "motorcycle", "bicycle"]


def to_devkit_box(scene, item, name, is_pred):
    """A DetectionBox from a sonardet box [x, y, z, l, w, h, yaw]; the devkit wants size as (w, l, h)
    and the yaw as a quaternion (w, x, y, z) about +z."""
    x, y, z, l, w, h, yaw = (float(v) for v in item["box"])
    kwargs = dict(
        sample_token=scene,
        translation=[x, y, z],
        size=[w, l, h],
        rotation=[math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)],
        velocity=[0.0, 0.0],
        detection_name=name,
        attribute_name="",
    )
    if is_pred:
        kwargs["detection_score"] = float(item["score"])
    return DetectionBox(**kwargs)


def run_case(case):
    names = dict(zip(case["classes"], DEVKIT_NAMES))
    if case.get("barrier_class"):  # the devkit scores barrier yaw with period pi
        names[case["barrier_class"]] = "barrier"
    gt, pred = EvalBoxes(), EvalBoxes()
    for scene in case["scenes"]:
        gt.add_boxes(scene, [to_devkit_box(scene, o, names[o["cls"]], False) for o in case["gt"].get(scene, [])])
        pred.add_boxes(scene, [to_devkit_box(scene, d, names[d["cls"]], True) for d in case["dets"].get(scene, [])])
    out = {}
    for cls in case["classes"]:
        res = {"ap": [], "precision": [], "confidence": [], "tp": None, "has_match": False}
        for th in case["thresholds"]:
            md = accumulate(gt, pred, names[cls], center_distance, float(th))
            res["ap"].append(calc_ap(md, case["min_recall"], case["min_precision"]))
            res["precision"].append(md.precision.tolist())
            res["confidence"].append(md.confidence.tolist())
            if float(th) == float(case["tp_threshold"]):
                res["tp"] = {k: calc_tp(md, case["min_recall"], k) for k in ("trans_err", "scale_err", "orient_err")}
                res["has_match"] = bool(np.any(md.confidence != 0))
        out[cls] = res
    return out


def main():
    req = json.load(sys.stdin)
    results = [run_case(c) for c in req["cases"]]
    json.dump({"devkit_version": version("nuscenes-devkit"), "numpy_version": np.__version__,
               "results": results}, sys.stdout)


if __name__ == "__main__":
    main()
