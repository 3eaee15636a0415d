"""Model-based detector: speed, work done and accuracy of the `paper` and `ours` variants.

For N scenes of a split (default: the first 5 of results/splits/dev.txt: never the test split) and each variant: seconds per
scene (per stage), windows / proposals, skipped ones, ICP runs, and the nuScenes centre-distance AP per
class at 0.5 m (sonardet.eval.evaluate.evaluate, visible ground truth only) with the mean over classes.
On the first scene it also reruns the paper variant with empty-window skipping disabled
(`skip_empty_windows: False`) and reports the time the skipping saves.

With ``--repeat R`` every scene is detected R times (all scenes once, then all again, so a drift of
the machine touches every scene alike) and, besides the mean of the first pass, the mean over scenes
of each scene's fastest and median pass is reported: a shared VM only ever slows a run down, so the
fastest of a few passes is the closer estimate of the time on an idle machine. The passes must give
the same detections (the detector is deterministic); a difference is an error.

    python benchmarks/detect.py [--scenes 5] [--split dev] [--variants paper,ours] [--results results]
                                [--params-ours '{"icp_xy_starts_m": 0}'] [--json out.json] [--no-skip-compare]
                                [--repeat 3] [--rankings '[{}, {"score": "tight_fitness"}]']

With ``--rankings``, `paper` settings that differ only in their ranking (e.g. the study's and the
improvement ladder's tight fitness) are timed each alone and all in one shared run, which registers
every window once (`ModelBasedDetector.rankings`, the workflow's shared job); their detections must
be equal.

Run it on 2 cores for the figures quoted in the README (e.g. `taskset -c 0,1 python benchmarks/detect.py`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from sonardet.detect.model_based import ModelBasedDetector
from sonardet.io.scenes import read_scene_points
from sonardet.io.templates import read_templates
from sonardet.objects import read_object


def read_inputs(results: Path):
    """Templates and objects of every class found under results/objects and results/templates;
    SystemExit naming the folder where it holds no object."""
    classes = sorted(p.stem for p in (results / "objects").glob("*.json"))
    if not classes:
        raise SystemExit(f"{results / 'objects'}: no object models here; build them and their templates first "
                         "(snakemake --cores 2 results/templates/tetrapod_s.npz and the other classes) or name the "
                         "results folder of a run with --results")
    objects = {c: read_object(results / "objects" / f"{c}.json") for c in classes}
    templates = {c: read_templates(results / "templates" / f"{c}.npz") for c in classes}
    return classes, objects, templates


def _fingerprint(dets) -> str:
    """The detections of one call as a canonical JSON text (compares two passes exactly)."""
    return json.dumps(dets, sort_keys=True, default=lambda o: o.tolist() if hasattr(o, "tolist") else repr(o))


def evaluate_map(gt: dict, dets: dict, objects: dict, classes: list) -> dict | None:
    """AP@0.5 m per class and mAP (None if the evaluation module is unavailable)."""
    try:
        from sonardet.eval.evaluate import evaluate
    except Exception as e:  # pragma: no cover - only when the evaluation module is broken
        print(f"evaluation unavailable: {e}")
        return None
    sym = [c for c in classes if objects[c].symmetry_order == 0]
    periods = {c: 2 * math.pi / objects[c].symmetry_order for c in classes if objects[c].symmetry_order > 1}
    r = evaluate(gt, dets, classes, [0.5, 1.0, 2.0, 4.0], 0.5, symmetric_classes=sym, yaw_periods_rad=periods)
    return {"mAP@0.5": r["mAP_headline"], "AP@0.5": {c: r["per_class"][c]["AP"]["0.5"] for c in classes},
            "n_gt": {c: r["per_class"][c]["n_gt"] for c in classes},
            "n_tp@0.5": {c: r["per_class"][c]["n_tp"]["0.5"] for c in classes},
            "n_pred": {c: r["per_class"][c]["n_pred"] for c in classes}}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results")
    ap.add_argument("--split", default="dev", help="split whose scenes are timed (default dev; the test split is for the final evaluation only)")
    ap.add_argument("--scenes", type=int, default=5, help="number of scenes of the split (0: all)")
    ap.add_argument("--variants", default="paper,ours")
    ap.add_argument("--params-ours", default="{}", help="JSON overrides of the ours defaults")
    ap.add_argument("--params-paper", default="{}", help="JSON overrides of the paper defaults")
    ap.add_argument("--no-skip-compare", action="store_true", help="skip the empty-window comparison")
    ap.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)),
                    help="worker threads of one detection call (default: the cores this process may use)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="passes over the scenes (>= 1); with more than one, the mean of each scene's fastest and "
                         "median pass is reported too")
    ap.add_argument("--rankings", default=None,
                    help='JSON list of paper ranking overrides (e.g. \'[{}, {"score": "tight_fitness"}]\': the '
                         'study and the ladder step): each alone, then all in one shared run, on every scene')
    ap.add_argument("--json", default=None, help="write all numbers to this JSON file")
    args = ap.parse_args()
    if args.repeat < 1:
        ap.error(f"--repeat must be at least 1, got {args.repeat}")
    results = Path(args.results)
    split_file = results / "splits" / f"{args.split}.txt"
    if not split_file.is_file():
        ap.error(f"{split_file}: no such split file; run the workflow first (snakemake --cores 2 makes the "
                 "scenes, templates and splits) or name the results folder of a run with --results")
    ids = split_file.read_text().split()
    if args.scenes > 0:
        ids = ids[: args.scenes]
    classes, objects, templates = read_inputs(results)
    params = {"ours": json.loads(args.params_ours), "paper": json.loads(args.params_paper)}
    print(f"{len(ids)} scene(s) of split '{args.split}', classes {classes}, "
          f"{os.cpu_count()} CPU(s) visible, affinity {len(os.sched_getaffinity(0))} core(s), "
          f"{args.threads} worker thread(s) per detection")
    gt = {}
    points = {}
    for sid in ids:
        meta = json.loads((results / "scenes" / f"{sid}.json").read_text())
        gt[sid] = [{"cls": o["cls"], "box": o["box"], "visible": o.get("visible", True)} for o in meta["objects"]]
        points[sid] = read_scene_points(results / "scenes" / f"{sid}.npz")["xyz"]
    out = {"scenes": ids, "threads": args.threads, "variants": {}}
    for variant in args.variants.split(","):
        rows, dets = [], {}
        detector = ModelBasedDetector(templates, objects, params[variant], variant, threads=args.threads)  # models built once
        for rep in range(args.repeat):
            for i, sid in enumerate(ids):
                d, st = detector(points[sid])
                tag = f" (pass {rep + 1}/{args.repeat})" if args.repeat > 1 else ""
                if rep > 0:
                    if _fingerprint(d) != _fingerprint(dets[sid]):
                        raise SystemExit(f"[{variant}] {sid}: pass {rep + 1} gave other detections than pass 1 "
                                         "(the detector should be deterministic)")
                    rows[i]["seconds_passes"].append(st["seconds"]["total"])
                    print(f"[{variant}] {sid}: {st['seconds']['total']:6.2f} s{tag}", flush=True)
                    continue
                dets[sid] = d
                rows.append({"scene": sid, "n_points": st["n_points"], "seconds": st["seconds"],
                             "seconds_passes": [st["seconds"]["total"]], "windows": st["windows"],
                             "windows_skipped": st["windows_skipped"], "icp_runs": st["icp_runs"],
                             "icp_runs_by_kind": dict(st.get("icp_runs_by_kind", {})),
                             "hypotheses": st["hypotheses"], "n_detections": len(d)})
                s = st["seconds"]
                print(f"[{variant}] {sid}: {s['total']:6.2f} s{tag} (ground {s['ground']:.2f}, proposals "
                      f"{s['proposals']:.2f}, registration {s['registration']:.2f}, scoring {s['scoring']:.2f}, "
                      f"selection {s['selection']:.2f}); {st['windows']} windows/proposals, {st['windows_skipped']} "
                      f"skipped, {st['icp_runs']} ICP runs, {len(d)} detections", flush=True)
        secs = np.array([r["seconds"]["total"] for r in rows])
        passes = np.array([r["seconds_passes"] for r in rows]).reshape(len(rows), -1)
        summary = {"seconds_per_scene_mean": float(secs.mean()), "seconds_per_scene_max": float(secs.max()),
                   "passes": args.repeat,
                   "seconds_per_scene_fastest_pass_mean": float(passes.min(1).mean()) if len(rows) else float("nan"),
                   "seconds_per_scene_median_pass_mean": float(np.median(passes, 1).mean()) if len(rows) else float("nan"),
                   "windows_mean": float(np.mean([r["windows"] for r in rows])),
                   "windows_skipped_mean": float(np.mean([r["windows_skipped"] for r in rows])),
                   "icp_runs_mean": float(np.mean([r["icp_runs"] for r in rows]))}
        ev = evaluate_map(gt, dets, objects, classes)
        if ev:
            summary.update(ev)
            print(f"[{variant}] mAP@0.5 m = {ev['mAP@0.5']:.4f}; AP@0.5 m per class: "
                  + ", ".join(f"{c} {ev['AP@0.5'][c]:.4f} ({ev['n_tp@0.5'][c]}/{ev['n_gt'][c]} TP, "
                              f"{ev['n_pred'][c]} predictions)" for c in classes))
        kinds = sorted({k for r in rows for k in r["icp_runs_by_kind"]})
        summary["icp_runs_by_kind_mean"] = {k: float(np.mean([r["icp_runs_by_kind"].get(k, 0) for r in rows]))
                                            for k in kinds}
        if kinds:
            print(f"[{variant}] ICP runs per scene by kind: "
                  + ", ".join(f"{k} {v:.0f}" for k, v in summary["icp_runs_by_kind_mean"].items()))
        print(f"[{variant}] {summary['seconds_per_scene_mean']:.2f} s per scene "
              f"(max {summary['seconds_per_scene_max']:.2f}); "
              f"{summary['windows_mean']:.0f} windows, {summary['windows_skipped_mean']:.0f} skipped, "
              f"{summary['icp_runs_mean']:.0f} ICP runs per scene")
        if args.repeat > 1:
            print(f"[{variant}] over {args.repeat} passes: {summary['seconds_per_scene_fastest_pass_mean']:.2f} s per "
                  f"scene (each scene's fastest pass), {summary['seconds_per_scene_median_pass_mean']:.2f} s (its "
                  "median pass); the same detections in every pass")
        out["variants"][variant] = {"summary": summary, "scenes": rows}
    if not args.no_skip_compare and ids:
        sid = ids[0]
        with_skip = ModelBasedDetector(templates, objects, params["paper"], "paper")
        without_skip = ModelBasedDetector(templates, objects, dict(params["paper"], skip_empty_windows=False), "paper")
        t0 = time.perf_counter()
        _, st_skip = with_skip(points[sid])
        t_skip = time.perf_counter() - t0
        t0 = time.perf_counter()
        _, st_all = without_skip(points[sid])
        t_all = time.perf_counter() - t0
        saved = t_all - t_skip
        print(f"[skip] {sid}, paper: {st_all['windows']} windows; skipping {st_skip['windows_skipped']} with too few "
              f"points above the seabed: {t_skip:.2f} s instead of {t_all:.2f} s ({st_skip['icp_runs']} instead of "
              f"{st_all['icp_runs']} ICP runs), {saved:.2f} s saved ({100 * saved / max(t_all, 1e-9):.0f} %)")
        out["skip_compare"] = {"scene": sid, "seconds_with_skip": t_skip, "seconds_without_skip": t_all,
                               "windows": st_all["windows"], "windows_skipped": st_skip["windows_skipped"],
                               "icp_runs_with_skip": st_skip["icp_runs"], "icp_runs_without_skip": st_all["icp_runs"]}
    if args.rankings:
        out["rankings"] = compare_rankings(json.loads(args.rankings), params["paper"], templates, objects, points)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


def compare_rankings(overrides: list, paper: dict, templates: dict, objects: dict, points: dict) -> dict:
    """Seconds per scene of `paper` settings that differ only in their ranking (`overrides`), each
    detector alone and all in one shared run (`ModelBasedDetector.rankings`), alternated per scene;
    the shared run's detections must equal each one's alone (else an error)."""
    alone = [ModelBasedDetector(templates, objects, {**paper, **o}, "paper") for o in overrides]
    shared = ModelBasedDetector(templates, objects, paper, "paper")
    t_alone, t_shared = [], []
    for sid, xyz in points.items():
        t0 = time.perf_counter()
        ref = [d(xyz)[0] for d in alone]
        t_alone.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        got = shared.rankings(xyz, overrides)
        t_shared.append(time.perf_counter() - t0)
        for o, r, (g, _) in zip(overrides, ref, got):
            if _fingerprint(r) != _fingerprint(g):
                raise SystemExit(f"[rankings] {sid}: the shared run's detections of {o} differ from its detector's alone")
        print(f"[rankings] {sid}: {len(overrides)} rankings alone {t_alone[-1]:.2f} s, in one run "
              f"{t_shared[-1]:.2f} s; the same detections", flush=True)
    row = {"overrides": overrides, "seconds_per_scene_alone": float(np.mean(t_alone)),
           "seconds_per_scene_shared": float(np.mean(t_shared)), "n_scenes": len(points)}
    print(f"[rankings] {len(overrides)} rankings of paper: {row['seconds_per_scene_alone']:.2f} s per scene one "
          f"detector each, {row['seconds_per_scene_shared']:.2f} s in one run; the same detections")
    return row


if __name__ == "__main__":
    main()
