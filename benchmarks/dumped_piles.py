"""Dumped tetrapod piles: AP of the pile members alone, on scenes made for this benchmark.

Real piles are dumped: 15-20 elements poured into a ring fence that is then removed, so the pile
slumps (sonardet.sim.layout, arrangement ``pile`` with a fence). The workflow's scenes hold such a
pile in a share ``scenes.dump_fraction`` of them; this benchmark makes N scenes with the project's
simulator where every scene has one (the config's scenes with ``dump_fraction`` 1 and a class mix
of 45 % tetrapod_s: one pile of ``dump_n`` elements, the class's other arranged elements in rows),
caches them under --out, runs each
model-based variant on them and prints, per variant, the nuScenes centre-distance AP at the headline
threshold of the objects in dumped piles (every object outside them is don't-care, as in
benchmarks/piles.py), by class, with its 95 % bootstrap interval over the scenes, the pile sizes,
the layers seen and the mAP of the whole scenes.

The scene ids (``d0000``...) are not workflow ids, and their seeds derive from the config's seed and
that id, so the scenes are neither test nor dev scenes of the workflow: like the dev sets, they are
for choosing and checking detector settings.

    python benchmarks/dumped_piles.py [--scenes 4] [--results results] [--config config/config.yaml]
                                      [--variants ours,paper] [--params-ours '{...}'] [--out DIR]
                                      [--json out.json]

Needs results/objects and results/templates (a workflow run's first steps:
``snakemake --cores 2 results/templates/tetrapod_s.npz`` and the other classes).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from detect import read_inputs  # benchmarks/detect.py
from piles import arrangement_ap, arrangement_interval, in_arrangement  # benchmarks/piles.py
from scene_cache import make_scenes  # benchmarks/scene_cache.py

from sonardet.config import read_config, validate_config
from sonardet.detect.model_based import ModelBasedDetector
from sonardet.eval.evaluate import evaluate
from sonardet.io.scenes import read_scene_points
from sonardet.objects import classes as class_specs

#: Share of the scene's objects that are tetrapod_s (the rest split evenly): with the default 50-60
#: objects, 22-27 tetrapod_s, so a scene's dumped pile (dump_fraction 1: one per scene) needs no
#: objects of other classes and some of the class remain for rows and scatter.
PILE_CLASS_SHARE = 0.45


def pile_config(cfg: dict, pile_class: str) -> dict:
    """The config's scenes with a dumped pile of `pile_class` in every scene and that class at
    PILE_CLASS_SHARE."""
    others = [c for c in cfg["classes"] if c != pile_class]
    mix = {c: (1 - PILE_CLASS_SHARE) / max(1, len(others)) for c in others} | {pile_class: PILE_CLASS_SHARE}
    raw = json.loads(json.dumps(cfg))
    raw["scenes"].update({"dump_fraction": 1.0, "class_mix": mix, "scatter_fraction": [0.1, 0.3]})
    return validate_config(raw, source="benchmarks/dumped_piles.py")


def _piles(meta: dict) -> str:
    """The sizes of a scene's dumped piles, for its progress line."""
    piles = Counter(o["group"] for o in meta["objects"] if in_arrangement(o, "dumped"))
    return f"dumped piles {sorted(piles.values())}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results", help="run folder with objects/ and templates/")
    ap.add_argument("--config", default="config/config.yaml")
    ap.add_argument("--scenes", type=int, default=4)
    ap.add_argument("--variants", default="ours")
    ap.add_argument("--params-ours", default="{}", help="JSON overrides of the ours defaults")
    ap.add_argument("--params-paper", default="{}", help="JSON overrides of the paper defaults")
    ap.add_argument("--out", default=None, help="scene cache (default: <results>/benchmarks/dumped_piles)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    results = Path(a.results)
    base = read_config(a.config)
    pile_class = next((c for c in base["classes"] if class_specs.get(c).arrangement == "pile"), None)
    if pile_class is None:
        raise SystemExit(f"{a.config}: no configured class has the pile arrangement")
    cfg = pile_config(base, pile_class)
    classes, objects, templates = read_inputs(results)
    ids = [f"d{k:04d}" for k in range(a.scenes)]
    out = Path(a.out) if a.out else results / "benchmarks" / "dumped_piles"
    print(f"{len(ids)} dumped-pile scene(s) under {out}; {os.cpu_count()} CPU(s), load {os.getloadavg()}", flush=True)
    make_scenes(cfg, objects, ids, out, describe=_piles)
    gt = {sid: [o for o in json.loads((out / f"{sid}.json").read_text())["objects"] if o.get("visible", True)]
          for sid in ids}
    points = {sid: read_scene_points(out / f"{sid}.npz")["xyz"] for sid in ids}
    members = [(s, o) for s, objs in gt.items() for o in objs if in_arrangement(o, "dumped")]
    sizes = sorted(Counter((s, o["group"]) for s, o in members).values())
    layers = dict(sorted(Counter(int(o.get("layer", 0)) for _, o in members).items()))
    ev = cfg["evaluation"]
    rows = []
    for variant in a.variants.split(","):
        params = json.loads(getattr(a, f"params_{variant}"))
        det = ModelBasedDetector(templates, objects, params, variant)
        dets, secs = {}, []
        for sid in ids:
            t = time.perf_counter()
            found, _ = det(points[sid])
            secs.append(time.perf_counter() - t)
            dets[sid] = [d for d in found if (d.get("extras") or {}).get("accepted", True)]
        whole = evaluate(gt, dets, classes, ev["dist_thresholds_m"], ev["headline_m"], min_recall=ev["min_recall"],
                         min_precision=ev["min_precision"])
        for cls, (ap_, n) in arrangement_ap(gt, dets, classes, "dumped", ev).items():
            if n:
                rows.append({"variant": variant, "class": cls, "AP_piles": ap_,
                             "AP_interval": arrangement_interval(gt, dets, cls, "dumped", ev), "objects": n,
                             "pile_sizes": sizes, "layers": layers, "mAP_scenes": whole["mAP_headline"],
                             "s_per_scene": sum(secs) / len(secs), "scenes": len(ids), "params": params,
                             "loadavg": list(os.getloadavg())})
    print("variant | class | AP@headline in dumped piles | 95 % interval (scenes) | members | pile sizes | "
          "members per layer | mAP of the scenes | s/scene | load")
    for r in rows:
        lo, hi = r["AP_interval"]
        print(f"{r['variant']} | {r['class']} | {r['AP_piles']:.3f} | {lo:.3f}-{hi:.3f} | {r['objects']} | "
              f"{r['pile_sizes']} | {r['layers']} | {r['mAP_scenes']:.3f} | {r['s_per_scene']:.1f} | "
              f"{' '.join(f'{v:.1f}' for v in r['loadavg'])}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
