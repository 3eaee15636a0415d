"""SASA's training batches: the time to prepare one, with and without domain randomisation.

Every training step first makes its batch on the CPU (`sonardet.detect.sasa.trainer._make_batch`):
the point sample of each scene, the augmentation and, with ``dr_enabled``, the randomised sensor
effects (`sonardet.detect.sasa.data.domain_randomise`) on the scene's whole point pool. This script
times that preparation alone, at the DEFAULTS batch (4 scenes of 8192 points), on the training
scenes of a finished run (``--results RUN``: never dev or test scenes), in rounds that alternate the
two modes, and prints per round and mode the median and fastest milliseconds per batch.

It also prints a SHA-256 digest of every batch it made (all tensors, in order, per mode): two
checkouts that give the same digest make the same batches, bit for bit, so a change meant to keep
the training's inputs can be checked with it (run it with each checkout's ``src`` first on
``PYTHONPATH``).

Usage: ``python benchmarks/sasa_batches.py --results RUN [--scenes 16] [--steps 16] [--repeat 3]
[--json out.json]``. One torch thread; compare rounds taken on the same machine at the same time.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import time
from pathlib import Path

import numpy as np
import torch


def training_scenes(results: Path, n: int, params: dict) -> list:
    """The first `n` training scenes of the run under `results` that exist, prepared for SASA."""
    from sonardet.detect.sasa.data import prepare_scene

    split = results / "splits" / "train.txt"
    if not split.is_file():
        raise SystemExit(f"{split}: no training split here; name the results folder of a run with --results")
    paths = [results / "scenes" / f"{sid}.npz" for sid in split.read_text().split()]
    paths = [p for p in paths if p.is_file()][:n]
    if not paths:
        raise SystemExit(f"{results / 'scenes'}: none of the training split's scenes exist")
    return [prepare_scene(p, params) for p in paths]


def batches(scenes: list, params: dict, steps: int, dr: bool, digest=None) -> list[float]:
    """Seconds of each of `steps` batches (batch size of `params`; seeded as training's epoch 0), the
    tensors fed into `digest` (a hashlib object) when given."""
    from sonardet.detect.sasa.trainer import _make_batch, _rng

    p = dict(params, dr_enabled=dr)
    bs = int(p["batch_size"])
    seed = int(p["seed"])
    times = []
    for step in range(steps):
        sel = [scenes[(step * bs + i) % len(scenes)] for i in range(bs)]
        rng = _rng(seed, "step", 0, step)
        dr_rng = _rng(seed, "dr", 0, step) if dr else None
        t = time.perf_counter()
        b = _make_batch(sel, p, rng, torch.device("cpu"), train_aug=True, dr_rng=dr_rng)
        times.append(time.perf_counter() - t)
        if digest is not None:
            for k in sorted(b):
                if torch.is_tensor(b[k]):
                    digest.update(k.encode())
                    digest.update(np.ascontiguousarray(b[k].numpy()).tobytes())
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", required=True, type=Path, help="results folder of a run (its training scenes)")
    ap.add_argument("--scenes", type=int, default=16, help="training scenes prepared and cycled through")
    ap.add_argument("--steps", type=int, default=16, help="batches per mode and round")
    ap.add_argument("--repeat", type=int, default=3, help="rounds, each timing both modes")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    from sonardet.detect.sasa import DEFAULTS, resolve_params

    params = resolve_params({}, base=DEFAULTS)
    scenes = training_scenes(args.results, args.scenes, params)
    pool = int(np.median([len(s.xyz) for s in scenes]))
    print(f"{len(scenes)} training scenes of {args.results} (median {pool} points after the ground filter), "
          f"batch {params['batch_size']} x {params['n_points']} points, one torch thread, "
          f"load average {os.getloadavg()[0]:.1f}")
    digests = {}
    for dr in (False, True):  # untimed: compiles what is compiled, gives the digest
        h = hashlib.sha256()
        batches(scenes, params, args.steps, dr, h)
        digests["dr" if dr else "plain"] = h.hexdigest()
    rows = []
    for r in range(args.repeat):
        for dr in (False, True):
            t = np.array(batches(scenes, params, args.steps, dr)) * 1e3
            row = {"round": r + 1, "mode": "dr" if dr else "plain", "median_ms": float(np.median(t)),
                   "fastest_ms": float(t.min()), "load": os.getloadavg()[0]}
            rows.append(row)
            print(f"round {row['round']} {row['mode']:>5}: median {row['median_ms']:.1f} ms per batch, "
                  f"fastest {row['fastest_ms']:.1f} ms (load {row['load']:.1f})", flush=True)
    for mode, d in digests.items():
        print(f"digest {mode}: {d}")
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "digests": digests, "scenes": len(scenes),
                                         "steps": args.steps}, indent=1))


if __name__ == "__main__":
    main()
