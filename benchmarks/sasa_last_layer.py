"""SASA training steps with the grouped MLPs' last layer fused with their pooling, against the two steps.

`sonardet.detect.sasa.backbone.FUSE_LAST_MAX` switches between the last batch norm + ReLU and the
max over the groups as one function (`weighted_batch_norm_relu_max`, the default) and the two
functions one after the other. This runs DEFAULTS training steps in pairs in one process: before
each pair the model and optimiser state are saved, then the same step (same batch, same seed) runs
once each way from that state, in alternating order; the two resulting models are compared bit for
bit (loss, every parameter and buffer) and the step times are paired. Prints, per pair, both step
times and whether the bits agree; then the medians and the mean paired difference with its 95 %
t-interval. Run on an otherwise idle machine; seconds depend on the machine and its load.

Usage: ``python benchmarks/sasa_last_layer.py [--results RUN] [--pairs 16] [--threads 1] [--scenes 16]
[--json out.json]`` (without ``--results``: synthetic box scenes; with it: the run's training scenes).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import stats


def _scene_paths(results: str | None, n: int, tmp: Path) -> list[Path]:
    if results is None:
        from sonardet.sim.boxes import write_box_scenes

        return write_box_scenes(tmp, n)
    split = Path(results) / "splits" / "train.txt"
    if not split.is_file():
        raise SystemExit(f"{split}: no training split here; name the results folder of a run with --results")
    return [Path(results) / "scenes" / f"{sid}.npz" for sid in split.read_text().split()[:n]]


def run(results: str | None, pairs: int, threads: int, n_scenes: int, warmup: int = 2) -> dict:
    """The paired steps (see the module docstring): a dict of per-pair times (s), bit agreement and
    the summary."""
    import torch

    from sonardet.detect.sasa import DEFAULTS, SASADetector, backbone, resolve_params
    from sonardet.detect.sasa.data import prepare_scene
    from sonardet.detect.sasa.trainer import _configure_process, _make_batch

    params = resolve_params({"num_threads": threads, "progress": False}, base=DEFAULTS)
    _configure_process(params)
    with tempfile.TemporaryDirectory() as tmp:
        scenes = [prepare_scene(p, params) for p in _scene_paths(results, n_scenes, Path(tmp))]
    torch.manual_seed(0)
    model = SASADetector(params)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=0.01)
    bs = int(params["batch_size"])
    cpu = torch.device("cpu")

    def step(i: int) -> tuple[float, float]:
        sel = [scenes[(i * bs + j) % len(scenes)] for j in range(bs)]
        batch = _make_batch(sel, params, np.random.default_rng(i), cpu, True)
        torch.manual_seed(1000 + i)
        t = time.perf_counter()
        loss, _ = model.loss(model(batch), batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        return time.perf_counter() - t, float(loss.detach())

    default = backbone.FUSE_LAST_MAX
    rows = []
    try:
        for i in range(warmup):
            backbone.FUSE_LAST_MAX = i % 2 == 0
            step(i)
        for i in range(pairs):
            saved_model, saved_opt = copy.deepcopy(model.state_dict()), copy.deepcopy(opt.state_dict())
            res = {}
            for fuse in ((True, False) if i % 2 == 0 else (False, True)):
                # copies again: the optimiser's load keeps the given tensors and the step updates them in place
                model.load_state_dict(copy.deepcopy(saved_model))
                opt.load_state_dict(copy.deepcopy(saved_opt))
                backbone.FUSE_LAST_MAX = fuse
                dt, loss = step(warmup + i)
                res[fuse] = (dt, loss, [t.detach().clone() for t in model.state_dict().values()])
            same = res[True][1] == res[False][1] and all(torch.equal(a, b) for a, b in zip(res[True][2], res[False][2]))
            rows.append({"pair": i, "fused_s": res[True][0], "two_steps_s": res[False][0], "same_bits": bool(same)})
            print(f"pair {i}: fused {res[True][0]:.3f} s, two steps {res[False][0]:.3f} s, same bits {same}", flush=True)
    finally:
        backbone.FUSE_LAST_MAX = default
    d = np.array([r["two_steps_s"] - r["fused_s"] for r in rows])
    half = float(stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else float("nan")
    summary = {"pairs": len(rows), "threads": threads, "scenes": "synthetic" if results is None else "run",
               "median_fused_s": float(np.median([r["fused_s"] for r in rows])),
               "median_two_steps_s": float(np.median([r["two_steps_s"] for r in rows])),
               "mean_saved_s": float(d.mean()), "saved_ci95_s": [float(d.mean()) - half, float(d.mean()) + half],
               "all_same_bits": all(r["same_bits"] for r in rows)}
    print(f"median step: fused {summary['median_fused_s']:.3f} s, two steps {summary['median_two_steps_s']:.3f} s; "
          f"saved {summary['mean_saved_s']:.3f} s per step (95 % t-interval {summary['saved_ci95_s'][0]:.3f} to "
          f"{summary['saved_ci95_s'][1]:.3f}, {len(rows)} pairs); same bits in every pair: {summary['all_same_bits']}")
    return {"rows": rows, "summary": summary}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default=None, help="a run's results folder (its training scenes)")
    ap.add_argument("--pairs", type=int, default=16)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--scenes", type=int, default=16)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    if args.pairs < 1:
        raise SystemExit("--pairs must be at least 1")
    out = run(args.results, args.pairs, args.threads, args.scenes)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    return out


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
