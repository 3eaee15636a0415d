"""SASA inference: one job per model against one job for all models on a dataset.

The workflow runs every SASA model on a dataset in one job (rules `detect_dataset_{dataset}_shared{k}`,
`sonardet.detect.sasa.infer_models`): PyTorch's import and the rest of a job's start-up are paid once,
and each scene is read and prepared once for all models. This times both ways as the workflow runs
them, each in fresh interpreters: one process per model (`infer` of that model) and one process for
all models (`infer_models`), and checks that every model's detections are the same both ways (exit 1
otherwise). It prints the wall and CPU seconds (user + system, of the processes) of each way, the
best of ``--repeat`` rounds, the two ways alternated.

Usage: ``python benchmarks/sasa_shared_inference.py --results RESULTS --models A/model.pt B/model.pt
[--dataset dev] [--scenes 10] [--repeat 3] [--threads 1]``. Scenes: the first ``--scenes`` of the
dataset's split file (`RESULTS/splits/{dataset}.txt`: dev, or train; never the test split). Seconds
depend on the machine and its load.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: What a child process runs: argv = models (comma-separated), scenes (comma-separated), threads, out.
CHILD = """
import json, sys
sys.path.insert(0, {src!r})
from sonardet.detect.sasa import TrainedSASA, infer_models
models, scenes, threads, out = sys.argv[1].split(","), sys.argv[2].split(","), int(sys.argv[3]), sys.argv[4]
loaded = [TrainedSASA.load(m, {{"num_threads": threads, "progress": False}}) for m in models]
res = infer_models(loaded, scenes)
json.dump([dets for dets, _ in res], open(out, "w"))
"""


def run_child(models: list[str], scenes: list[str], threads: int, out: Path) -> tuple[float, float]:
    """Wall and CPU seconds of one fresh interpreter running `models` on `scenes` (detections to out)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", CHILD.format(src=str(REPO / "src")), ",".join(models), ",".join(scenes),
                    str(threads), str(out)], check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def digest(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", required=True, type=Path, help="a results folder with splits/ and scenes/")
    ap.add_argument("--models", required=True, nargs="+", help="model.pt files (two or more)")
    ap.add_argument("--dataset", default="dev", choices=["dev", "train"], help="split whose scenes are read")
    ap.add_argument("--scenes", type=int, default=10, help="the first N scenes of the split")
    ap.add_argument("--repeat", type=int, default=3, help="rounds, the two ways alternated; the best is kept")
    ap.add_argument("--threads", type=int, default=1, help="torch threads per process (the workflow's sasa.threads)")
    args = ap.parse_args(argv)
    split = args.results / "splits" / f"{args.dataset}.txt"
    ids = split.read_text().split()[:args.scenes]
    scenes = [str(args.results / "scenes" / f"{i}.npz") for i in ids]
    missing = [s for s in scenes if not Path(s).exists()]
    if missing or not ids:
        sys.exit(f"{split}: scenes missing under {args.results / 'scenes'} ({missing[:3]}); make them first "
                 f"(snakemake --cores 2 {' '.join(missing[:3])})")
    if len(args.models) < 2:
        sys.exit("--models: name two or more model.pt files")
    best = {"per model": (float("inf"), float("inf")), "shared": (float("inf"), float("inf"))}
    hashes = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeat):
            wall = cpu = 0.0
            alone = []
            for k, m in enumerate(args.models):
                out = Path(tmp) / f"alone{k}.json"
                w, c = run_child([m], scenes, args.threads, out)
                wall, cpu = wall + w, cpu + c
                alone += json.loads(out.read_text())
            best["per model"] = min(best["per model"], (wall, cpu))
            out = Path(tmp) / "shared.json"
            best["shared"] = min(best["shared"], run_child(args.models, scenes, args.threads, out))
            shared = json.loads(out.read_text())
            hashes[r] = ([digest(d) for d in alone], [digest(d) for d in shared])
            print(f"round {r + 1}: detections per model {hashes[r][0]}, shared {hashes[r][1]}", flush=True)
    same = all(a == s for a, s in hashes.values()) and len({json.dumps(v) for v in hashes.values()}) == 1
    print(f"{len(args.models)} models, {len(scenes)} {args.dataset} scenes, {args.threads} torch thread(s), "
          f"best of {args.repeat} rounds:")
    for way, (w, c) in best.items():
        print(f"  {way:10s} {w:7.2f} s wall  {c:7.2f} s CPU")
    print(f"  saved      {best['per model'][0] - best['shared'][0]:7.2f} s wall  "
          f"{best['per model'][1] - best['shared'][1]:7.2f} s CPU")
    print("detections: " + ("the same both ways" if same else "DIFFERENT"))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
