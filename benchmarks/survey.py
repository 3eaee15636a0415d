"""A large survey through `sonardet detect` (tiles in parallel) and, optionally, through the workflow's
per-tile jobs: wall seconds, soundings per second, peak memory, and the mAP against the objects cast.

Two kinds of survey, both in UTM coordinates (EPSG:32610):

* cast (default): 200 m x 200 m with 1,400 objects (the study site's size and object count; about 8 M
  soundings at the default sensor), cast as benchmarks/detect_jobs.py casts its surveys: an fBm seabed,
  objects of the four classes in turn at random yaws, here placed at least `--gap-m` apart (no two
  footprints touch: a survey of lone objects, not of piles), surveyed by parallel MBES lines along x
  (Embree ray casting with the sensor's noise and dropouts);
* `--mosaic SPLIT`: the first `--mosaic-n` (default 25) scenes of a split (results/splits/SPLIT.txt;
  the test split is refused) laid side by side on a square grid of their extents (25 default scenes:
  200 m x 200 m, about 7 M soundings, ~1,350 objects in the default distribution: row piles, ring
  stacks, cone clusters, tumbled objects, rocks), each scene's soundings shifted so that its median
  depth is the first scene's (scenes differ in mean depth and slope, so seams keep steps of a few
  decimetres); ground truth: the scenes' visible objects, boxes shifted alike.

The object models and templates come from ``--results`` (objects/{cls}.json|.ply, templates/{cls}.npz;
a finished workflow's folder), else they are built here from the config (reduced templates, as in the
tests; `--mosaic` needs a finished workflow's folder).

1. `sonardet detect --jobs J` (default J: the cores this process may use) as a child process, its memory
   sampled every 0.5 s: peak of the summed PSS (proportional set size: pages the forked tile workers
   share with the parent count once, split among them) and peak of the summed RSS (shared pages counted
   in every process: an upper bound) over the process and its children; the summary line's detection
   seconds and soundings per second; the wall time of the whole command (reading, tiling, writing).
2. With `--workflow`, the same survey file through the workflow (`snakemake --cores J` on
   `results/surveys/bench/summary.json` in a scratch copy of the workflow: checkpoint `survey_tiles`,
   one `detect_survey_tile` job per tile, `survey_detections`), with the object models and templates
   copied in; the wall time of the snakemake command.
3. The detections (accepted and down-weighted ones, as written) scored against the cast objects' boxes
   (`sonardet.eval.evaluate`, centre distance 0.5 m, the survey as one scene, no 500-box cap: it holds
   more objects than that): mAP and AP per class, so a speed figure comes with its accuracy.

    python benchmarks/survey.py [--extent-m 200] [--objects 1400] [--gap-m 0.5] [--jobs J]
                                [--mosaic train --mosaic-n 25] [--tile-m 50] [--results results]
                                [--cache survey.npz] [--workflow] [--json out.json]

`--cache F` keeps the cast survey (soundings and objects) in F and reuses it when F exists with the same
extent, object count, gap and seed. Run it on 2 cores for figures comparable with README's (`taskset -c
0,1 python benchmarks/survey.py`); every timing line ends with the load averages (1, 5, 15 min).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from detect_jobs import UTM, cast_survey, models_folder  # benchmarks/detect_jobs.py

from sonardet.survey import DEFAULT_TILE_M

REPO = Path(__file__).resolve().parent.parent
CRS = "EPSG:32610"
MATCH_M = 0.5


def load() -> str:
    return "load " + " ".join(f"{v:.1f}" for v in os.getloadavg())


class MemorySampler:
    """Peak summed PSS and RSS (bytes) of a process and its descendants, sampled every `period_s`."""

    def __init__(self, pid: int, period_s: float = 0.5):
        import psutil

        self._root = psutil.Process(pid)
        self._period = period_s
        self.peak_pss = 0
        self.peak_rss = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _sample(self) -> None:
        import psutil

        pss = rss = 0
        try:
            procs = [self._root] + self._root.children(recursive=True)
        except psutil.Error:
            return
        for p in procs:
            try:
                m = p.memory_full_info()
            except psutil.Error:
                continue
            pss += getattr(m, "pss", m.rss)
            rss += m.rss
        self.peak_pss = max(self.peak_pss, pss)
        self.peak_rss = max(self.peak_rss, rss)

    def _run(self) -> None:
        while not self._stop.is_set():
            self._sample()
            self._stop.wait(self._period)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()


def survey_file(cfg: dict, results: Path, args, tmp: Path) -> tuple[Path, list, int]:
    """The survey as a points file (npz, UTM) and the objects cast (class, pose), reusing --cache."""
    from sonardet.io.points import PointCloud, read_points, write_points

    key = {"extent_m": args.extent_m, "objects": args.objects, "gap_m": args.gap_m, "seed": args.seed}
    meta = args.cache.with_suffix(".json") if args.cache else None
    if meta is not None and meta.is_file() and args.cache.is_file() and json.loads(meta.read_text())["key"] == key:
        placed = json.loads(meta.read_text())["objects"]
        n = len(read_points(args.cache).xyz)
        print(f"survey: {n} soundings from {args.cache} (cached)")
        return args.cache, placed, n
    t = time.perf_counter()
    xyz, placed = cast_survey(cfg, results, args.extent_m, args.objects, args.seed, gap_m=args.gap_m)
    path = args.cache or tmp / "survey.npz"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_points(path, PointCloud(xyz, crs=CRS))
    if meta is not None:
        meta.write_text(json.dumps({"key": key, "objects": placed}))
    print(f"survey: {len(xyz)} soundings over {args.extent_m:g} m x {args.extent_m:g} m, {args.objects} objects "
          f"{args.gap_m:g} m apart, cast in {time.perf_counter() - t:.1f} s")
    return path, placed, len(xyz)


def mosaic_file(results: Path, split: str, n: int, tmp: Path) -> tuple[Path, list[dict], int]:
    """The first n scenes of a split side by side (module doc) as a points file (npz, UTM) and their
    visible objects as ground truth (cls, box in the survey frame)."""
    from sonardet.io.points import PointCloud, write_points
    from sonardet.io.scenes import read_scene_points

    if split == "test":
        raise SystemExit("--mosaic test: the test split is read only by the final evaluation; use train or dev")
    ids = (results / "splits" / f"{split}.txt").read_text().split()[:n]
    k = int(np.ceil(np.sqrt(len(ids))))
    parts, gt, z_ref = [], [], None
    for i, sid in enumerate(ids):
        doc = json.loads((results / "scenes" / f"{sid}.json").read_text())
        x0, x1, y0, y1 = doc["extent"]
        xyz = read_scene_points(results / "scenes" / f"{sid}.npz")["xyz"]
        z_med = float(np.median(xyz[:, 2]))
        z_ref = z_med if z_ref is None else z_ref
        shift = np.array([(i % k) * (x1 - x0) - x0, (i // k) * (y1 - y0) - y0, z_ref - z_med])
        parts.append(xyz + shift + UTM)
        for o in doc["objects"]:
            if o.get("visible", True):
                box = np.asarray(o["box"], dtype=np.float64)
                box[:3] += shift + UTM
                gt.append({"cls": o["cls"], "box": [float(v) for v in box]})
    xyz = np.concatenate(parts)
    path = tmp / "mosaic.npz"
    write_points(path, PointCloud(xyz, crs=CRS))
    print(f"survey: {len(ids)} {split} scenes side by side ({k} x {k} grid), {len(xyz)} soundings, {len(gt)} visible objects")
    return path, gt, len(xyz)


def ground_truth(placed: list, results: Path) -> list[dict]:
    """Boxes of the cast objects (survey frame, m), as the simulator annotates them (`canonical_box`)."""
    from sonardet.geometry import quat_from_yaw
    from sonardet.objects import read_object
    from sonardet.objects.catalog import canonical_box

    objs = {}
    out = []
    for cls, pos, yaw in placed:
        o = objs.setdefault(cls, read_object(results / "objects" / f"{cls}.json"))
        box = canonical_box(np.asarray(o.mesh.vertices), pos, quat_from_yaw(yaw), o.symmetry_order)
        out.append({"cls": cls, "box": [float(v) for v in box]})
    return out


def score(gt: list[dict], detections_json: Path, results: Path, classes: list[str]) -> dict:
    """mAP@0.5 m and AP per class of the written detections against the cast objects (one scene)."""
    from sonardet.eval.evaluate import evaluate
    from sonardet.objects import read_object

    doc = json.loads(detections_json.read_text())
    dets = [{"cls": d["cls"], "box": d["box"], "score": float(d["score"])} for d in doc["detections"]]
    objs = {c: read_object(results / "objects" / f"{c}.json") for c in classes}
    sym = [c for c in classes if objs[c].symmetry_order == 0]
    periods = {c: 2 * np.pi / objs[c].symmetry_order for c in classes if objs[c].symmetry_order > 1}
    r = evaluate({"survey": gt}, {"survey": dets}, classes, [MATCH_M], MATCH_M, symmetric_classes=sym,
                 yaw_periods_rad=periods, max_boxes_per_scene=None)
    return {"mAP@0.5": r["mAP_headline"], "AP@0.5": {c: r["per_class"][c]["AP"][str(MATCH_M)] for c in classes},
            "n_gt": len(gt), "n_detections": len(dets)}


def run_cli(survey: Path, results: Path, out: Path, args) -> dict:
    """`sonardet detect` on the survey in a child process: seconds, memory peaks, its summary line."""
    exe = shutil.which("sonardet", path=str(Path(sys.executable).parent)) or "sonardet"
    cmd = [exe, "detect", "--input", str(survey), "--out", str(out), "--results", str(results), "--crs", CRS,
           "--tile-m", str(args.tile_m), "--quiet"] + (["--jobs", str(args.jobs)] if args.jobs else [])
    t = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    mem = MemorySampler(proc.pid)
    stdout, stderr = proc.communicate()
    mem.stop()
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"sonardet detect failed (exit {proc.returncode}):\n{stderr[-3000:]}")
    line = stdout.strip().splitlines()[-1]
    m = re.search(r"(\d+) tile\(s\).*?([\d.]+) s detection \((\d+) soundings/s", line)
    return {"wall_seconds": wall, "tiles": int(m.group(1)), "detect_seconds": float(m.group(2)),
            "soundings_per_second": int(m.group(3)), "peak_pss_bytes": mem.peak_pss, "peak_rss_bytes": mem.peak_rss,
            "summary": line}


def run_workflow(survey: Path, results: Path, work: Path, args) -> dict:
    """The survey through the workflow's per-tile jobs in a scratch copy of the workflow: seconds."""
    for name in ("Snakefile", "rules", "workflow_scripts", "config", "environment.yml", "profiles"):
        src = REPO / name
        (shutil.copytree if src.is_dir() else shutil.copy2)(src, work / name)
    for sub in ("objects", "templates"):
        shutil.copytree(results / sub, work / "results" / sub)
    cores = args.jobs or len(os.sched_getaffinity(0))
    cfg = {"surveys": {"bench": {"path": str(survey), "crs": CRS, "tile_m": args.tile_m}}}
    (work / "bench.json").write_text(json.dumps(cfg))
    cmd = [sys.executable, "-m", "snakemake", "results/surveys/bench/summary.json", "--cores", str(cores),
           "--rerun-triggers", "mtime", "--configfile", "bench.json"]
    t = time.perf_counter()
    proc = subprocess.run(cmd, cwd=work, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t
    if proc.returncode != 0:
        raise SystemExit(f"the workflow failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    n_tiles = len(list((work / "results" / "surveys" / "bench" / "tile_detections").glob("*.json")))
    return {"wall_seconds": wall, "tiles": n_tiles, "cores": cores, "rules": rule_breakdown(work / "results", wall),
            "detections_json": work / "results" / "surveys" / "bench" / "detections.json"}


def rule_breakdown(results: Path, wall_s: float) -> dict:
    """Where the workflow's wall time went, from its Snakemake benchmark files: per rule the jobs, their
    summed wall and CPU seconds and the span (first start to last end, s); `outside_jobs_s` is the wall
    time of the snakemake command during which no job ran (start-up, DAG, checkpoint re-evaluation)."""
    from sonardet.report.timeline import read_benchmarks

    df = read_benchmarks(results / "benchmarks")
    out = {}
    for rule, g in df.groupby("rule"):
        out[rule] = {"jobs": len(g), "seconds_sum": float(g["seconds"].sum()), "cpu_s_sum": float(g["cpu_s"].sum()),
                     "span_s": float(g["end"].max() - g["start"].min()),
                     "seconds_max": float(g["seconds"].max())}
    busy, end = 0.0, -np.inf
    for s_, e_ in sorted(zip(df["start"], df["end"])):  # union of the job intervals
        if e_ > end:
            busy += e_ - max(s_, end)
            end = e_
    out["outside_jobs_s"] = float(wall_s - busy) if len(df) else float(wall_s)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--extent-m", type=float, default=200.0, help="survey side in metres (default 200)")
    ap.add_argument("--objects", type=int, default=1400, help="objects on the seabed (default 1400)")
    ap.add_argument("--gap-m", type=float, default=0.5, help="least gap between two objects' footprints (m)")
    ap.add_argument("--tile-m", type=float, default=DEFAULT_TILE_M,
                    help=f"largest tile side in metres (default {DEFAULT_TILE_M:g}, the CLI's and the workflow's)")
    ap.add_argument("--jobs", type=int, default=None, help="tiles at once (default: the cores this process may use)")
    ap.add_argument("--results", type=Path, default=None,
                    help="folder holding objects/ and templates/ (default: built here from the config)")
    ap.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--mosaic", default=None, help="lay the first --mosaic-n scenes of this split side by side")
    ap.add_argument("--mosaic-n", type=int, default=25, help="scenes in the mosaic (default 25)")
    ap.add_argument("--cache", type=Path, default=None, help="keep / reuse the cast survey in this .npz file")
    ap.add_argument("--workflow", action="store_true", help="also run the survey through the workflow's tile jobs")
    ap.add_argument("--no-cli", action="store_true",
                    help="skip `sonardet detect` (with --workflow: time only the workflow)")
    ap.add_argument("--keep", type=Path, default=None, help="keep the workflow's scratch folder here (must not exist)")
    ap.add_argument("--json", default=None, help="write the numbers to this JSON file")
    args = ap.parse_args()
    from sonardet.config import read_config

    cfg = read_config(args.config)
    classes = list(cfg["classes"])
    out: dict = {"extent_m": args.extent_m, "objects": args.objects, "gap_m": args.gap_m, "tile_m": args.tile_m,
                 "cpus_visible": os.cpu_count(), "affinity": len(os.sched_getaffinity(0))}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        results = models_folder(cfg, args.results, tmp)
        if args.mosaic:
            survey, gt, n = mosaic_file(results, args.mosaic, args.mosaic_n, tmp)
            out.update(mosaic=args.mosaic, mosaic_n=args.mosaic_n)
        else:
            survey, placed, n = survey_file(cfg, results, args, tmp)
            gt = ground_truth(placed, results)
        out["n_soundings"] = n
        if not args.no_cli:
            cli = run_cli(survey, results, tmp / "cli" / "survey.json", args)
            cli.update(score(gt, tmp / "cli" / "survey.json", results, classes))
            print(f"sonardet detect: {cli['tiles']} tiles, {cli['wall_seconds']:.1f} s wall ({cli['detect_seconds']:.1f} s "
                  f"detection, {cli['soundings_per_second']} soundings/s), peak memory {cli['peak_pss_bytes'] / 1e9:.2f} GB "
                  f"PSS ({cli['peak_rss_bytes'] / 1e9:.2f} GB RSS summed), mAP@0.5 {cli['mAP@0.5']:.3f} "
                  f"({cli['n_detections']} detections, {cli['n_gt']} objects); {load()}")
            print("  AP@0.5 " + ", ".join(f"{c} {v:.3f}" for c, v in cli["AP@0.5"].items()))
            out["cli"] = cli
        if args.workflow:
            work = args.keep or tmp / "workflow"
            work.mkdir(parents=True)
            wf = run_workflow(survey, results, work, args)
            wf.update(score(gt, wf.pop("detections_json"), results, classes))
            print(f"workflow (snakemake --cores {wf['cores']}): {wf['tiles']} tile jobs, {wf['wall_seconds']:.1f} s "
                  f"wall, mAP@0.5 {wf['mAP@0.5']:.3f}; {load()}")
            for rule, r in wf["rules"].items():
                if rule == "outside_jobs_s":
                    continue
                print(f"  {rule}: {r['jobs']} job(s), span {r['span_s']:.1f} s, wall summed {r['seconds_sum']:.1f} s "
                      f"(longest {r['seconds_max']:.1f} s), CPU summed {r['cpu_s_sum']:.1f} s")
            print(f"  no job running: {wf['rules']['outside_jobs_s']:.1f} s of the wall time (snakemake start-up, DAG, "
                  f"checkpoint re-evaluation)")
            out["workflow"] = wf
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
