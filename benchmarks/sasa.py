"""Speed and memory of the SASA detector (sonardet.detect.sasa): training step, inference, epoch cost.

For each configuration (``DEFAULTS`` = the 2-core CPU budget, ``STUDY`` = the study's network: batch
8, 16384 raw points, reference widths and nsample) and each device (CPU always, CUDA when available;
``--device`` picks one) a fresh subprocess (so that peak memory is its own):

1. prepares the scenes (ground filter, local frame) and reports the seconds per scene;
2. times ``--steps`` training steps (forward, loss, backward, AdamW step; augmentation included)
   at the configuration's batch size after ``--warmup`` untimed steps -> seconds per step;
3. times inference (sampling, network, NMS) on each scene -> seconds per scene (random weights:
   every candidate passes the score threshold, so NMS sees its worst case);
4. reports peak resident memory (``ru_maxrss``, MB) and, on CUDA, peak allocated GPU memory;
5. extrapolates the cost of one epoch over ``--train-scenes`` (default 80) scenes and of the whole
   schedule (``epochs`` of the configuration).

Scenes: ``results/scenes/*.npz`` listed in ``results/splits/train.txt`` (the first ``--n-scenes``);
with ``--synthetic`` (or when none exist) synthetic scenes of the same size are made on the fly.

``--padded`` runs the grouped MLPs on the padded ball-query slots (``compact_groups: false``, the
earlier computation, bit for bit) instead of the distinct neighbours, to compare the two.

The step time is the median of the timed steps, and the fastest of them beside it (a shared VM only
slows a step down); on a shared machine compare rows taken at the same time (the machine's load
average is printed). ``--system-malloc`` leaves glibc's allocator as it is (freed memory goes back
to the system, ``retain_freed_memory: false``) and ``--parallel-min-elements N`` moves the size from
which the fused kernels run in parallel, to compare both with the defaults. A STUDY step on CPU
takes seconds to tens of seconds: ``--steps 2`` keeps the run to a few minutes.

Usage: ``python benchmarks/sasa.py [--threads 2] [--steps 5] [--configs DEFAULTS,STUDY] [--device cpu]
[--padded] [--synthetic] [--json out.json]``. Timings are machine-dependent: compare rows taken on the
same machine only.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import platform
import queue
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
#: The configurations --configs may name (sonardet.detect.sasa.DEFAULTS and STUDY).
CONFIGS = ("DEFAULTS", "STUDY")


def _scene_paths(n: int, synthetic: bool, tmp: Path) -> list[Path]:
    split = REPO / "results" / "splits" / "train.txt"
    if not synthetic and split.exists():
        ids = split.read_text().split()
        paths = [REPO / "results" / "scenes" / f"{i}.npz" for i in ids]
        paths = [p for p in paths if p.exists()][:n]
        if len(paths) == n:
            return paths
    from sonardet.sim.boxes import write_box_scenes

    return write_box_scenes(tmp, n)  # 40 m x 40 m, ~180 points/m^2, 55 box-shaped elements


def _profile_step(step, dev, rows: int, shapes: bool = False) -> str:
    """The ``rows`` operators of one training step with the most self time (device time on CUDA);
    with ``shapes``, one row per operator and input shapes (e.g. each matrix product's sizes)."""
    from torch.profiler import ProfilerActivity, profile

    acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev.type == "cuda" else [])
    with profile(activities=acts, record_shapes=shapes) as prof:
        step(0)
    key = "self_cuda_time_total" if dev.type == "cuda" else "self_cpu_time_total"
    return prof.key_averages(group_by_input_shape=shapes).table(sort_by=key, row_limit=rows)


def _worker(name: str, overrides: dict, paths: list[str], steps: int, warmup: int, threads: int, device: str | None,
            train_scenes: int, fps_loop: bool, profile_rows: int, parallel_min: int | None, q,
            profile_shapes: bool = False) -> None:
    import torch

    from sonardet.detect.sasa import DEFAULTS, STUDY, SASADetector, TrainedSASA, resolve_params
    from sonardet.detect.sasa.data import prepare_scene
    from sonardet.detect.sasa.ops import gpu_kernels, kernels, sampling
    from sonardet.detect.sasa.trainer import _configure_process, _make_batch, peak_memory_mb, resolve_device

    if fps_loop:  # FPS on the PyTorch loop on every device (no compiled CPU kernel, no Triton kernel)
        sampling.kernels, gpu_kernels.AVAILABLE = None, False
    if parallel_min is not None and kernels is not None:
        kernels.PARALLEL_MIN_ELEMENTS = int(parallel_min)
    base = {"DEFAULTS": DEFAULTS, "STUDY": STUDY}[name]
    params = resolve_params({**overrides, "num_threads": threads}, base=base)
    _configure_process(params)
    dev = resolve_device(device)
    bs = int(params["batch_size"])
    t0 = time.perf_counter()
    scenes = [prepare_scene(p, params) for p in paths]
    prep = (time.perf_counter() - t0) / len(scenes)
    torch.manual_seed(0)
    model = SASADetector(params).to(dev)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3, weight_decay=0.01)

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    def step(i: int) -> None:
        sel = [scenes[(i * bs + j) % len(scenes)] for j in range(bs)]
        batch = _make_batch(sel, params, np.random.default_rng(i), dev, True)
        loss, _ = model.loss(model(batch), batch)
        opt.zero_grad()
        loss.backward()
        opt.step()

    times = []
    for i in range(warmup + steps):
        sync()
        t = time.perf_counter()
        step(i)
        sync()
        if i >= warmup:
            times.append(time.perf_counter() - t)
    step_s = float(np.median(times))
    profile = _profile_step(step, dev, profile_rows, profile_shapes) if profile_rows else None
    inf = []
    trained = TrainedSASA(model, params, dev)
    for i, s in enumerate(scenes):
        sync()
        t = time.perf_counter()
        trained.detect_scene(s)
        sync()
        if i > 0 or len(scenes) == 1:
            inf.append(time.perf_counter() - t)
    steps_per_epoch = math.ceil(train_scenes / bs)
    q.put({
        "config": name, "device": str(dev), "threads": threads, "batch_size": bs, "n_points": int(params["n_points"]),
        "n_params": sum(p.numel() for p in model.parameters()),
        "prepare_s_per_scene": prep, "train_s_per_step": step_s, "train_s_per_step_min": float(np.min(times)),
        "train_s_per_scene": step_s / bs, "infer_s_per_scene": float(np.median(inf)),
        "epoch_s_est": step_s * steps_per_epoch, "train_scenes": train_scenes, "epochs": int(params["epochs"]),
        "schedule_s_est": step_s * steps_per_epoch * int(params["epochs"]),
        "fps": "torch loop" if fps_loop else "default", "profile": profile,
        "freed_memory_kept": bool(params["retain_freed_memory"]),
        "kernels_parallel_min_elements": kernels.PARALLEL_MIN_ELEMENTS if kernels is not None else None,
        "gpu": torch.cuda.get_device_name(dev) if dev.type == "cuda" else None, "torch": torch.__version__,
        **peak_memory_mb(dev),
    })


def _result(q, proc, what: str) -> dict:
    """The row the worker process `proc` puts on `q`; SystemExit naming `what` if the worker ends
    without one (its traceback is on stderr above), instead of waiting for it forever."""
    while True:
        try:
            return q.get(timeout=1.0)
        except queue.Empty:
            if not proc.is_alive():
                try:  # a row put just before the worker ended
                    return q.get(timeout=1.0)
                except queue.Empty:
                    raise SystemExit(f"benchmarks/sasa.py: the worker for {what} ended (exit code {proc.exitcode}) "
                                     "without a result; its error is above") from None


def _devices(device: str | None) -> list[str]:
    """The devices to time: the one asked for, else CPU and (when available) CUDA."""
    if device is not None:
        return [device]
    import torch

    return ["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"]


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=5, help="timed training steps per configuration")
    ap.add_argument("--warmup", type=int, default=1)
    ap.add_argument("--n-scenes", type=int, default=8, help="scenes loaded (>= the STUDY batch size)")
    ap.add_argument("--train-scenes", type=int, default=80, help="training-set size for the epoch estimate")
    ap.add_argument("--configs", default="DEFAULTS,STUDY")
    ap.add_argument("--device", default=None, help="cpu or cuda (default: cpu, and cuda too if available)")
    ap.add_argument("--padded", action="store_true", help="grouped MLPs on the padded slots (compact_groups false)")
    ap.add_argument("--system-malloc", action="store_true",
                    help="leave glibc's allocator as it is (retain_freed_memory false: freed blocks go back to the "
                         "system)")
    ap.add_argument("--parallel-min-elements", type=int, default=None, metavar="N",
                    help="the fused batch-norm and segment-max kernels run in parallel on arrays of at least N "
                         "values (default: sonardet's PARALLEL_MIN_ELEMENTS; 0: always)")
    ap.add_argument("--synthetic", action="store_true", help="use synthetic scenes even if results/ has some")
    ap.add_argument("--fps-loop", action="store_true",
                    help="FPS on the PyTorch loop (not the compiled CPU kernel or the Triton CUDA kernel)")
    ap.add_argument("--profile", type=int, default=0, metavar="ROWS",
                    help="profile one more training step and print its ROWS most expensive operators")
    ap.add_argument("--profile-shapes", action="store_true",
                    help="with --profile: one row per operator and input shapes (e.g. each matrix product's sizes)")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    unknown = [n for n in args.configs.split(",") if n not in CONFIGS]
    if unknown:
        ap.error(f"--configs: unknown configuration(s) {unknown}; known: {','.join(CONFIGS)}")
    rows = []
    overrides = {"progress": False, "compact_groups": not args.padded,
                 "retain_freed_memory": not args.system_malloc}
    with tempfile.TemporaryDirectory() as tmp:
        paths = [str(p) for p in _scene_paths(args.n_scenes, args.synthetic, Path(tmp))]
        ctx = mp.get_context("spawn")
        for device in _devices(args.device):
            for name in args.configs.split(","):
                q = ctx.Queue()
                proc = ctx.Process(target=_worker, args=(name, overrides, paths, args.steps, args.warmup,
                                                         args.threads, device, args.train_scenes, args.fps_loop,
                                                         args.profile, args.parallel_min_elements, q,
                                                         args.profile_shapes))
                proc.start()
                row = _result(q, proc, f"{name} on {device}")
                proc.join()
                row["load_avg_1min"] = os.getloadavg()[0]
                rows.append(row)
    cpu = platform.processor() or platform.machine()
    for r in rows:
        if r["profile"]:
            print(f"profile of one {r['config']} step on {r['device']}:\n{r['profile']}")
    gpus = sorted({r["gpu"] for r in rows if r["gpu"]})
    print(f"machine: {platform.node()} {cpu}{' + ' + ', '.join(gpus) if gpus else ''}, torch {rows[0]['torch']}, "
          f"torch threads {args.threads}, FPS {'on the PyTorch loop' if args.fps_loop else 'default'}, "
          f"scenes: {len(paths)} "
          f"({'synthetic' if 'syn' in Path(paths[0]).stem else 'results/scenes'}), grouped MLPs on "
          f"{'padded slots' if args.padded else 'distinct neighbours'}, freed memory "
          f"{'returned to the system' if args.system_malloc else 'kept'}, fused kernels parallel from "
          f"{rows[0]['kernels_parallel_min_elements']} values, load average {os.getloadavg()[0]:.1f}")
    head = ("config", "device", "batch", "points", "params", "s/step", "fastest", "s/scene(train)", "s/scene(infer)",
            "prep s/scene", f"epoch s ({args.train_scenes} sc.)", "schedule h", "peak RSS MB", "load")
    print(" | ".join(head))
    for r in rows:
        print(" | ".join([r["config"], r["device"], str(r["batch_size"]), str(r["n_points"]), f"{r['n_params']:,}",
                          f"{r['train_s_per_step']:.2f}", f"{r['train_s_per_step_min']:.2f}",
                          f"{r['train_s_per_scene']:.2f}", f"{r['infer_s_per_scene']:.2f}",
                          f"{r['prepare_s_per_scene']:.2f}", f"{r['epoch_s_est']:.0f}",
                          f"{r['schedule_s_est'] / 3600:.2f} ({r['epochs']} ep.)", f"{r['peak_rss_mb']:.0f}",
                          f"{r['load_avg_1min']:.1f}"]))
    if args.json:
        Path(args.json).write_text(json.dumps({"machine": platform.node(), "rows": rows}, indent=1))
    return rows


if __name__ == "__main__":
    main()
