"""Model-based detector: how close a scene's detection is to its floor cost, and how its time scales.

What it measures, for the first N scenes of a split (default: 5 of results/splits/dev.txt; the test
split is refused, it is for the final evaluation only) and one variant (default `ours`):

1. Floor and detection per scene, in seconds (wall clock, `time.perf_counter`):
   (a) reading the scene's soundings (`sonardet.io.scenes.read_scene_points`),
   (b) building a scipy cKDTree on its points (x, y, z),
   (c) the detector's seabed model (`sonardet.detect.model_based.ground.seabed`, called as the
       detector calls it: on the points shifted to the local origin, with the detector's resolved
       parameters),
   floor = a + b + c: what any detector that reads the scene, indexes it and models its seabed pays;
   (d) the full detection (`ModelBasedDetector(...)` called on the points, as benchmarks/detect.py
       does; the class models are built once, before any timing).
   Printed per scene: a, b, c, floor, d, d / floor, soundings and objects (the count of objects in
   the scene JSON beside the npz), then the means.
2. Scaling with soundings: on the first scene, the detection on the points subsampled to 0.25x and
   0.5x (random subset, fixed seed) and densified to 2x and 4x (the original points plus k - 1 copies
   of each, jittered by N(0, 0.005 m) per coordinate, fixed seed), with the 1x time of part 1; the
   exponent b of seconds = a * soundings^b is fitted by least squares on log-log.
3. Scaling with objects: the same fit of the detection seconds of part 1 against the objects per
   scene (the printed range says how many objects the fit covers; the scenes also differ in
   soundings and layout, so read it as a rough trend, not a law). With `--object-counts 0,25,50,...`
   it is measured on scenes made for it instead: for each count k >= 1 one 40 x 40 m scene of the
   config's distribution (arrangements, rocks, sensor) with exactly k objects (`scenes.n_objects`
   [k, k]; ids ``n0001``, ``n0025``..., seeds from the config's seed and the id, so neither test nor
   dev scenes; cached under <results>/benchmarks/object_scaling), timed like part 1 and scored
   (mean AP at the headline distance over the classes present, accepted boxes), and the exponent
   fitted over the counts.

    python benchmarks/detect_floor.py [--scenes 5] [--split dev] [--variant ours|paper]
                                      [--results results] [--ids s0100,s0101] [--json out.json]
                                      [--object-counts 1,25,50,100,150] [--config config/config.yaml]

`--scenes 0` (or more than the split holds) takes every scene of the split. `--ids` names the scenes
instead of a split file (for a results folder without results/splits/; ids listed in
results/splits/test.txt are refused). Every output row ends with the load average (1, 5, 15 min).

Timings are machine-dependent: quote them with the machine (CPU, cores the process may use) and the
load averages printed beside them; on a loaded machine the ratios (d / floor, the exponents) are
more stable than the seconds, but still not free of the load.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))

from detect import read_inputs  # benchmarks/detect.py
from scene_cache import make_scenes  # benchmarks/scene_cache.py

from sonardet.config import read_config, validate_config
from sonardet.detect.model_based import ModelBasedDetector
from sonardet.detect.model_based.ground import seabed
from sonardet.eval.evaluate import evaluate
from sonardet.io.origin import choose_origin
from sonardet.io.scenes import read_scene_points

SUBSAMPLE = (0.25, 0.5)
DENSIFY = (2, 4)
JITTER_M = 0.005
SEED = 20240601


def load() -> str:
    """The load average (1, 5, 15 min) as a short string for an output row."""
    a = os.getloadavg()
    return f"load {a[0]:.2f}/{a[1]:.2f}/{a[2]:.2f}"


def loadavg() -> list[float]:
    return [float(v) for v in os.getloadavg()]


def fit_power(x, y) -> dict:
    """Least-squares fit of log y = log a + b log x; {'a', 'b'} (None when x takes fewer than 2 values)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ok = (x > 0) & (y > 0)
    if len(np.unique(x[ok])) < 2:
        return {"a": None, "b": None, "n": int(ok.sum())}
    b, loga = np.polyfit(np.log(x[ok]), np.log(y[ok]), 1)
    return {"a": float(np.exp(loga)), "b": float(b), "n": int(ok.sum())}


def scene_ids(results: Path, split: str, ids_arg: str | None, n: int) -> list[str]:
    """The scene ids to time: --ids, else the split file; the test split and test ids are refused."""
    if split == "test":
        sys.exit("refusing --split test: the test split is for the final evaluation only; use dev")
    test_file = results / "splits" / "test.txt"
    if ids_arg:
        ids = [s for s in ids_arg.split(",") if s]
        if test_file.exists():
            bad = sorted(set(ids) & set(test_file.read_text().split()))
            if bad:
                sys.exit(f"refusing test scenes {bad}: the test split is for the final evaluation only")
        else:
            print(f"note: {test_file} not found; could not check that --ids holds no test scene")
    else:
        f = results / "splits" / f"{split}.txt"
        if not f.exists():
            sys.exit(f"{f} not found: build the split files first, or name dev scenes with --ids")
        ids = f.read_text().split()
    if n > 0 and n < len(ids):
        ids = ids[:n]
    elif n > len(ids):
        print(f"note: {n} scenes asked for, {len(ids)} available: timing all of them")
    return ids


def time_floor(results: Path, sid: str, params: dict) -> tuple[np.ndarray, dict]:
    """Read the scene, build a cKDTree, model the seabed; the points and the seconds of each."""
    t = time.perf_counter()
    xyz = read_scene_points(results / "scenes" / f"{sid}.npz")["xyz"]
    t_read = time.perf_counter() - t
    t = time.perf_counter()
    tree = cKDTree(xyz)
    t_tree = time.perf_counter() - t
    del tree
    t = time.perf_counter()
    local = xyz - choose_origin(xyz)  # the detector's local frame
    seabed(local, params)
    t_ground = time.perf_counter() - t
    return xyz, {"read": t_read, "kdtree": t_tree, "ground": t_ground,
                 "floor": t_read + t_tree + t_ground}


def time_detect(detector, xyz: np.ndarray) -> tuple[float, dict, int]:
    """Wall seconds of one detector call, its stats and the number of detections."""
    t = time.perf_counter()
    dets, st = detector(xyz)
    return time.perf_counter() - t, st, len(dets)


def parse_counts(text: str | None) -> list[int]:
    """The --object-counts list (ascending, distinct); exits naming the flag on a bad entry."""
    if not text:
        return []
    try:
        counts = sorted({int(c) for c in text.split(",") if c.strip()})
    except ValueError:
        sys.exit(f"--object-counts {text!r}: expected comma-separated integers, e.g. 0,25,50,100,150")
    if not counts or counts[0] < 1:
        # The config refuses scenes without objects (nothing to evaluate); part 1's floor is the
        # cost of a scene's seabed without detection.
        sys.exit(f"--object-counts {text!r}: expected counts >= 1 (e.g. 1,25,50,100,150)")
    return counts


def objects_over_part1(v: str, rows: list[dict]) -> dict:
    """Part 3 without --object-counts: the power fit of part 1's seconds against its scenes' objects."""
    objs = [r["objects"] for r in rows]
    fo = fit_power(objs, [r["detect_s"] for r in rows])
    sn = [r["soundings"] for r in rows]
    rng_note = f"{len(rows)} scene(s), {min(objs)}-{max(objs)} objects and {min(sn)}-{max(sn)} soundings per scene"
    if fo["b"] is None:
        print(f"[{v}] seconds = a * objects^b: no fit ({rng_note}: needs 2 distinct counts)  {load()}")
    else:
        print(f"[{v}] seconds = a * objects^b: b = {fo['b']:.2f} (a = {fo['a']:.3g}; {rng_note}, a "
              f"{max(objs) / max(min(objs), 1):.2f}x range of objects)  {load()}", flush=True)
    return {"objects": objs, "detect_s": [r["detect_s"] for r in rows], "fit": fo,
            "objects_min": min(objs), "objects_max": max(objs)}


def present_map(res: dict) -> float | None:
    """The mean AP at the headline distance over the classes the scene holds (the metric's mAP counts
    an absent class as AP 0, which would make a scene of few objects look bad); None without any."""
    aps = [next(a for th, a in pc["AP"].items() if float(th) == float(res["headline_m"]))
           for pc in res["per_class"].values() if pc["n_gt"] > 0]
    return float(np.mean(aps)) if aps else None


def object_sweep(args, results: Path, detector, objects: dict, classes: list[str]) -> dict:
    """Part 3 with --object-counts: one scene per count made for it, timed and scored; the power fit."""
    v = args.variant
    base = read_config(args.config)
    out_dir = results / "benchmarks" / "object_scaling"
    ev = base["evaluation"]
    print(f"[{v}] part 3: detection seconds against objects per scene ({args.config}, scenes under {out_dir})",
          flush=True)
    rows = []
    for k in parse_counts(args.object_counts):
        raw = json.loads(json.dumps(base))
        raw["scenes"]["n_objects"] = [k, k]
        cfg = validate_config(raw, source=f"benchmarks/detect_floor.py --object-counts ({k} objects)")
        sid = f"n{k:04d}"
        make_scenes(cfg, objects, [sid], out_dir)
        xyz = read_scene_points(out_dir / f"{sid}.npz")["xyz"]
        gt_all = json.loads((out_dir / f"{sid}.json").read_text())["objects"]
        gt = [o for o in gt_all if o.get("visible", True)]
        t = time.perf_counter()
        found, _ = detector(xyz)
        d = time.perf_counter() - t
        dets = [x for x in found if (x.get("extras") or {}).get("accepted", True)]
        m = present_map(evaluate({sid: gt}, {sid: dets}, classes, ev["dist_thresholds_m"], ev["headline_m"],
                                 min_recall=ev["min_recall"], min_precision=ev["min_precision"]))
        rows.append({"scene": sid, "objects": len(gt_all), "visible": len(gt), "soundings": len(xyz),
                     "detect_s": d, "n_detections": len(dets), "mAP": m, "loadavg": loadavg()})
        print(f"{sid:>7} objects {len(gt_all):>4d} (visible {len(gt):>4d}) soundings {len(xyz):>8d} "
              f"detect {d:>7.2f} s  detections {len(dets):>4d}  mAP {'-' if m is None else f'{m:.3f}'}  {load()}",
              flush=True)
    fo = fit_power([r["objects"] for r in rows], [r["detect_s"] for r in rows])
    if fo["b"] is None:
        print(f"[{v}] seconds = a * objects^b: no fit (needs 2 distinct counts)  {load()}")
    else:
        print(f"[{v}] seconds = a * objects^b: b = {fo['b']:.2f} (a = {fo['a']:.3g}; {len(rows)} scenes, "
              f"{rows[0]['objects']}-{rows[-1]['objects']} objects)  {load()}", flush=True)
    return {"config": args.config, "rows": rows, "fit": fo}

def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results")
    ap.add_argument("--split", default="dev", help="split whose scenes are timed (default dev; test is refused)")
    ap.add_argument("--scenes", type=int, default=5, help="number of scenes of the split (0: all)")
    ap.add_argument("--ids", default=None, help="comma-separated scene ids instead of the split file")
    ap.add_argument("--variant", default="ours", choices=["ours", "paper"])
    ap.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)),
                    help="worker threads of one detection call (default: the cores this process may use)")
    ap.add_argument("--json", default=None, help="write all numbers to this JSON file")
    ap.add_argument("--object-counts", default=None,
                    help="comma-separated objects per scene for part 3 (e.g. 1,25,50,100,150): scenes made for it")
    ap.add_argument("--config", default="config/config.yaml", help="config of the --object-counts scenes")
    args = ap.parse_args()
    results = Path(args.results)
    ids = scene_ids(results, args.split, args.ids, args.scenes)
    if not ids:
        sys.exit("no scenes to time")
    parse_counts(args.object_counts)  # a bad flag fails before anything is built
    classes, objects, templates = read_inputs(results)
    t = time.perf_counter()
    detector = ModelBasedDetector(templates, objects, {}, args.variant, threads=args.threads)
    build = time.perf_counter() - t
    v = args.variant
    print(f"[{v}] {len(ids)} scene(s) ({'--ids' if args.ids else 'split ' + args.split}), classes {classes}; "
          f"{os.cpu_count()} CPU(s) visible, affinity {len(os.sched_getaffinity(0))} core(s), "
          f"{args.threads} worker thread(s) per detection; detector built in {build:.2f} s (not timed below); {load()}", flush=True)
    out = {"variant": v, "split": None if args.ids else args.split, "scenes": ids, "classes": classes,
           "cpu_count": os.cpu_count(), "affinity": len(os.sched_getaffinity(0)), "threads": args.threads,
           "build_seconds": build,
           "loadavg_start": loadavg(), "per_scene": [], "soundings_scaling": {}, "objects_scaling": {}}

    # Warm-up (untimed): the first detector call pays one-off costs (lazy imports, allocator, caches).
    xyz0 = read_scene_points(results / "scenes" / f"{ids[0]}.npz")["xyz"]
    warm = xyz0[np.sort(np.random.default_rng(SEED).choice(len(xyz0), max(3, len(xyz0) // 20), replace=False))]
    detector(warm)
    del xyz0, warm

    # 1. floor and detection per scene
    hdr = (f"{'scene':>7} {'soundings':>9} {'objects':>7} {'read_s':>7} {'kdtree_s':>8} {'ground_s':>8} "
           f"{'floor_s':>7} {'detect_s':>8} {'d/floor':>7}")
    print(f"[{v}] part 1: floor (a read + b cKDTree + c seabed) and detection (d) per scene")
    print(hdr + "  load 1/5/15 min", flush=True)
    first_xyz = None
    for sid in ids:
        xyz, fl = time_floor(results, sid, detector.params)
        n_obj = len(json.loads((results / "scenes" / f"{sid}.json").read_text())["objects"])
        d, st, n_det = time_detect(detector, xyz)
        row = {"scene": sid, "soundings": len(xyz), "objects": n_obj, **{f"{k}_s": x for k, x in fl.items()},
               "detect_s": d, "ratio": d / fl["floor"], "detector_seconds": st["seconds"],
               "n_detections": n_det, "loadavg": loadavg()}
        out["per_scene"].append(row)
        print(f"{sid:>7} {len(xyz):>9d} {n_obj:>7d} {fl['read']:>7.3f} {fl['kdtree']:>8.3f} {fl['ground']:>8.3f} "
              f"{fl['floor']:>7.3f} {d:>8.2f} {row['ratio']:>7.1f}  {load()}", flush=True)
        if first_xyz is None:
            first_xyz = xyz
    rows = out["per_scene"]
    mean = {k: float(np.mean([r[k] for r in rows])) for k in
            ("soundings", "objects", "read_s", "kdtree_s", "ground_s", "floor_s", "detect_s", "ratio")}
    mean["ratio_of_means"] = mean["detect_s"] / mean["floor_s"]
    out["mean"] = mean
    print(f"{'mean':>7} {mean['soundings']:>9.0f} {mean['objects']:>7.1f} {mean['read_s']:>7.3f} "
          f"{mean['kdtree_s']:>8.3f} {mean['ground_s']:>8.3f} {mean['floor_s']:>7.3f} {mean['detect_s']:>8.2f} "
          f"{mean['ratio']:>7.1f}  {load()}  (ratio of the means {mean['ratio_of_means']:.1f})", flush=True)

    # 2. scaling with soundings on the first scene
    sid = ids[0]
    rng = np.random.default_rng(SEED)
    print(f"[{v}] part 2: detection seconds against soundings, scene {sid} (subsampled / densified, seed {SEED})")
    print(f"{'factor':>7} {'soundings':>9} {'detect_s':>8} {'s/1e5 pts':>9} {'detections':>10}  load 1/5/15 min",
          flush=True)
    srows = []
    for f in SUBSAMPLE + (1,) + DENSIFY:
        if f == 1:
            pts, d, n_det = first_xyz, rows[0]["detect_s"], rows[0]["n_detections"]
            note = "  (part 1)"
        else:
            if f < 1:
                pick = np.sort(rng.choice(len(first_xyz), round(f * len(first_xyz)), replace=False))
                pts = first_xyz[pick]
            else:
                copies = np.repeat(first_xyz, f - 1, axis=0)
                copies += rng.normal(0.0, JITTER_M, copies.shape)
                pts = np.concatenate([first_xyz, copies])
                del copies
            d, _, n_det = time_detect(detector, pts)
            note = ""
        r = {"factor": f, "soundings": len(pts), "detect_s": d, "n_detections": n_det, "loadavg": loadavg()}
        srows.append(r)
        print(f"{f:>7} {len(pts):>9d} {d:>8.2f} {1e5 * d / len(pts):>9.3f} {n_det:>10d}  {load()}{note}",
              flush=True)
        del pts
    fs = fit_power([r["soundings"] for r in srows], [r["detect_s"] for r in srows])
    out["soundings_scaling"] = {"scene": sid, "seed": SEED, "jitter_m": JITTER_M, "rows": srows, "fit": fs}
    print(f"[{v}] seconds = a * soundings^b: b = {fs['b']:.2f} (a = {fs['a']:.3g}; {fs['n']} points, "
          f"{srows[0]['soundings']}-{srows[-1]['soundings']} soundings)  {load()}", flush=True)

    # 3. scaling with objects
    if args.object_counts:
        out["objects_scaling"] = object_sweep(args, results, detector, objects, classes)
    else:
        out["objects_scaling"] = objects_over_part1(v, rows)
    out["loadavg_end"] = loadavg()
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
        print(f"numbers written to {args.json}")


if __name__ == "__main__":
    main()
