"""AP of the objects in piles and stacks alone: how a detector does where objects lie on each other.

For one dataset of a finished run (default: the dev scenes; the test split is for the final
evaluation only) and each method given, every visible ground-truth object that is not in the chosen
arrangement is made don't-care (`ignore`: a detection on it is neither a true nor a false positive,
`sonardet.eval.matching`), and the nuScenes centre-distance AP at the headline threshold is computed
per class with the project's evaluator (`sonardet.eval.evaluate.evaluate`), with its 95 % bootstrap
interval over scenes (`sonardet.eval.bootstrap`, 1000 resamples, seed 0). Rows: method, arrangement,
class, AP, interval, objects (visible, in that arrangement), the largest group (objects of one pile or
stack) and the layers seen.

    python benchmarks/piles.py [--results results] [--dataset dev] [--methods model_based_ours,...]
                               [--arrangements pile,dumped,stack] [--json out.json]

Needs results/detections/<method>/<dataset>/*.json and the scene JSONs (results/scenes, or
results/mismatch/scenes for the mismatch sets).
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

from sonardet.config import read_config
from sonardet.eval.bootstrap import bootstrap_map, interval, scene_flags
from sonardet.eval.evaluate import evaluate
from sonardet.io.annotations import read_detections

SCENE_DIRS = {"dev": "scenes", "synthetic": "scenes", "mismatch": "mismatch/scenes", "mismatch_dev": "mismatch/scenes"}


def in_arrangement(obj: dict, arrangement: str) -> bool:
    """Whether a ground-truth object belongs to `arrangement`: its scene JSON's `arrangement`, or, for
    the pseudo-arrangement 'dumped', the members of a dumped pile (`dumped`; their arrangement is 'pile')."""
    if arrangement == "dumped":
        return bool(obj.get("dumped", False))
    return obj.get("arrangement") == arrangement


def _marked(gt: dict, arrangement: str) -> dict:
    """gt with every object outside `arrangement` made don't-care."""
    return {s: [{**o, "ignore": not in_arrangement(o, arrangement)} for o in objs] for s, objs in gt.items()}


def arrangement_interval(gt: dict, dets: dict, cls: str, arrangement: str, ev: dict,
                         n_resamples: int = 1000) -> tuple[float, float]:
    """95 % percentile bootstrap interval over scenes of class `cls`'s AP at ev['headline_m'] over the
    visible objects of `arrangement` (others don't-care), as `arrangement_ap` computes it."""
    scenes = sorted(gt)
    flags = scene_flags(_marked(gt, arrangement), dets, [cls], scenes, float(ev["headline_m"]))
    samples = bootstrap_map({"m": flags}, n_resamples, 0, ev["min_recall"], ev["min_precision"])["m"]
    return interval(samples)


def arrangement_ap(gt: dict, dets: dict, classes: list, arrangement: str, ev: dict) -> dict:
    """Class -> AP at ev['headline_m'] over the visible objects of `arrangement` (others don't-care;
    `in_arrangement`)."""
    res = evaluate(_marked(gt, arrangement), dets, classes, ev["dist_thresholds_m"], ev["headline_m"],
                   min_recall=ev["min_recall"], min_precision=ev["min_precision"])
    key = repr(float(ev["headline_m"]))
    return {c: (float(v["AP"][key]), int(v["n_gt"])) for c, v in res["per_class"].items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default="results")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--dataset", default="dev")
    ap.add_argument("--methods", default="model_based_ours")
    ap.add_argument("--arrangements", default="pile,dumped,stack",
                    help="arrangements to score; 'dumped' is the members of dumped piles (a subset of 'pile')")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    if a.dataset in ("synthetic", "mismatch"):
        raise SystemExit(f"--dataset {a.dataset}: a test set; measure on dev or mismatch_dev (the test split is read "
                         "only by the final evaluation)")
    res = Path(a.results)
    cfg = read_config(a.config)
    ev, classes = cfg["evaluation"], list(cfg["classes"])
    rows = []
    for method in a.methods.split(","):
        files = sorted((res / "detections" / method / a.dataset).glob("*.json"))
        if not files:
            hint = (" (the development sets' detections and scenes come from `snakemake --cores 2 development`)"
                    if a.dataset != "dev" else "")
            raise SystemExit(f"{res / 'detections' / method / a.dataset}: no detections{hint}")
        gt, dets = {}, {}
        for f in files:
            scene = json.loads((res / SCENE_DIRS.get(a.dataset, "scenes") / f.name).read_text())
            gt[f.stem] = [o for o in scene["objects"] if o.get("visible", True)]
            dets[f.stem] = [d for d in read_detections(f, classes)["detections"]
                            if (d.get("extras") or {}).get("accepted", True)]
        for arr in a.arrangements.split(","):
            members = [(s, o) for s, objs in gt.items() for o in objs if in_arrangement(o, arr)]
            groups = Counter((s, o.get("group")) for s, o in members)
            layers = sorted({int(o.get("layer", 0)) for _, o in members})
            for cls, (ap_, n) in arrangement_ap(gt, dets, classes, arr, ev).items():
                if n:
                    rows.append({"method": method, "dataset": a.dataset, "arrangement": arr, "class": cls, "AP": ap_,
                                 "AP_interval": arrangement_interval(gt, dets, cls, arr, ev), "objects": n,
                                 "largest_group": max(groups.values()), "layers": layers, "scenes": len(gt)})
    print("method | dataset | arrangement | class | AP@headline | 95 % interval | objects | largest group | layers | "
          "scenes")
    for r in rows:
        lo, hi = r["AP_interval"]
        print(f"{r['method']} | {r['dataset']} | {r['arrangement']} | {r['class']} | {r['AP']:.3f} | "
              f"{lo:.3f}-{hi:.3f} | {r['objects']} | {r['largest_group']} | {r['layers']} | {r['scenes']}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
