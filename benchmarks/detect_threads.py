"""`ours` on one thread against N worker threads: where the threads' time goes, round by round.

`ModelBasedDetector(threads=N)` runs the independent pieces of each round (proposal maps, fits,
scores, refits) on N threads (`sonardet.detect.model_based.tasks`). For the first S scenes of a split
(default: 3 dev scenes; never the test split) it detects every scene at 1 and at N threads, in
alternated passes, records every round (`tasks.recording`) and reports per kind of piece:

- the rounds' wall seconds, the pieces' own seconds summed, and the bound max(longest piece,
  summed / N) that N threads could reach if each piece kept its own time;
- the seconds outside the rounds (seabed, trees, rasters, selection: one thread);
- how much longer a piece takes beside the others at N threads than alone (the summed seconds at N
  threads over those at 1): time the pieces spend waiting for each other, e.g. for the GIL, which
  the NumPy glue, Open3D's ray casting and voxel thinning hold.

The detections at 1 and at N threads must be the same (the detector's contract); a difference is an
error.

    python benchmarks/detect_threads.py [--results results] [--scenes 3] [--threads 2] [--passes 2]
                                        [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import defaultdict
from pathlib import Path

from detect import _fingerprint, read_inputs
from detect_floor import scene_ids
from sonardet.detect.model_based import ModelBasedDetector
from sonardet.detect.model_based.tasks import recording
from sonardet.io.scenes import read_scene_points


def summarise(records, threads: int, wall_s: float) -> dict:
    """Per piece kind: rounds, items, wall s, summed piece s and the bound max(longest, sum / threads)
    summed over the rounds; with the totals and the seconds outside the rounds (wall_s less theirs)."""
    kinds = defaultdict(lambda: {"rounds": 0, "items": 0, "wall_s": 0.0, "task_s": 0.0, "bound_s": 0.0})
    for r in records:
        k = kinds[r.name]
        k["rounds"] += 1
        k["items"] += r.items
        k["wall_s"] += r.wall_s
        k["task_s"] += sum(r.task_s)
        k["bound_s"] += max(max(r.task_s, default=0.0), sum(r.task_s) / threads)
    rounds_wall = sum(k["wall_s"] for k in kinds.values())
    return {"kinds": dict(kinds), "rounds_wall_s": rounds_wall,
            "task_s": sum(k["task_s"] for k in kinds.values()),
            "bound_s": sum(k["bound_s"] for k in kinds.values()), "outside_s": wall_s - rounds_wall,
            "wall_s": wall_s}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--results", default="results")
    ap.add_argument("--split", default="dev", help="split whose scenes are used (never the test split)")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--threads", type=int, default=len(os.sched_getaffinity(0)),
                    help="worker threads compared with one (default: the usable cores)")
    ap.add_argument("--passes", type=int, default=2, help="alternated passes of each thread count")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    if args.threads < 2 or args.passes < 1 or args.scenes < 1:
        ap.error("--threads must be at least 2, --passes and --scenes at least 1")
    results = Path(args.results)
    try:
        ids = scene_ids(results, args.split, None, args.scenes)  # refuses the test split
    except SystemExit as refused:
        ap.error(str(refused))
    _, objects, templates = read_inputs(results)
    points = {sid: read_scene_points(results / "scenes" / f"{sid}.npz")["xyz"] for sid in ids}
    detectors = {n: ModelBasedDetector(templates, objects, {}, "ours", threads=n) for n in (1, args.threads)}
    detectors[1](points[ids[0]])  # compiled kernels and the classes' caches warm before any timing
    print(f"{len(ids)} scene(s) of '{args.split}', 1 against {args.threads} threads, {args.passes} pass(es) "
          f"each, load {os.getloadavg()[0]:.2f}", flush=True)
    passes, reference = {1: [], args.threads: []}, {}
    for p in range(args.passes):
        for n, det in detectors.items():
            with recording() as records:
                t = time.perf_counter()
                for sid in ids:
                    dets, _ = det(points[sid])
                    fp = _fingerprint(dets)
                    if reference.setdefault(sid, fp) != fp:
                        raise SystemExit(f"{sid}: other detections at {n} thread(s) (pass {p + 1}) than in the "
                                         "first run; the detector must not depend on its thread count")
                wall = time.perf_counter() - t
            s = summarise(records, n, wall)
            passes[n].append(s)
            print(f"pass {p + 1}, {n} thread(s): {wall / len(ids):.2f} s/scene; rounds {s['rounds_wall_s'] / len(ids):.2f} "
                  f"s/scene (pieces {s['task_s'] / len(ids):.2f}, bound {s['bound_s'] / len(ids):.2f}), outside "
                  f"{s['outside_s'] / len(ids):.2f}", flush=True)
    one, many = passes[1][-1], passes[args.threads][-1]
    print(f"\nlast pass, per scene: {'kind':42s} {'rounds':>6s} {'items':>6s} {'wall 1':>7s} "
          f"{'wall N':>7s} {'pieces N/1':>10s} {'bound N':>8s}")
    for name, k1 in sorted(one["kinds"].items(), key=lambda kv: -kv[1]["wall_s"]):
        kn = many["kinds"].get(name, {"wall_s": 0.0, "task_s": 0.0, "bound_s": 0.0})
        ratio = kn["task_s"] / k1["task_s"] if k1["task_s"] > 0 else float("nan")
        print(f"{'':21s} {name:42s} {k1['rounds'] / len(ids):6.1f} {k1['items'] / len(ids):6.1f} "
              f"{k1['wall_s'] / len(ids):7.2f} {kn['wall_s'] / len(ids):7.2f} {ratio:10.2f} {kn['bound_s'] / len(ids):8.2f}")
    best = {n: min(s["wall_s"] for s in v) / len(ids) for n, v in passes.items()}
    print(f"fastest pass: {best[1]:.2f} s/scene at 1 thread, {best[args.threads]:.2f} at {args.threads} "
          f"({best[1] / best[args.threads]:.2f}x); the pieces take {many['task_s'] / one['task_s']:.2f}x their "
          f"one-thread seconds beside each other; identical detections")
    if args.json:
        Path(args.json).write_text(json.dumps({"scenes": ids, "threads": args.threads, "passes":
                                               {str(n): v for n, v in passes.items()}}, indent=1))


if __name__ == "__main__":
    main()
