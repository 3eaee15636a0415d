"""Timings of the SASA point operators (sonardet.detect.sasa.ops).

Runs on CPU with 2 threads (the default experiment's budget) and, when CUDA is available, on the
GPU too. On CPU, FPS / S-FPS and the ball query are timed on the compiled kernels (``[compiled]``, the
default there; on CUDA FPS runs the Triton kernel, ``[triton]``) and on the PyTorch paths
(``[torch]`` loop; ``tiled`` / ``dense`` ball query), which
give the same indices. Prints a table; ``--json PATH`` also writes the rows for the report.

Workload: a synthetic seabed-like cloud (x, y uniform over 40 m x 40 m, z a gentle surface with
a few 1-2 m mounds), the SASA sampling chain 16384 -> 4096 -> 1024 -> 512 points, the ball
queries of an SA1 layer with sonar radii (0.4 / 0.8 / 1.2 m, nsample 16 / 16 / 32), grouping of
64-channel features, the compact grouped MLP's weighted batch norm and max pooling (fused kernels
against PyTorch; its last layer's batch norm and the pooling as one function against the two), and
rotated NMS / IoU on 500 boxes clustered around 25 objects.

Peak memory of the ball query is measured in a fresh subprocess (ru_maxrss growth) so earlier
allocations do not hide it.

Usage: ``python benchmarks/sasa_ops.py [--quick | --rows-only | --cuda-only] [--repeat 3] [--threads 2]
[--json out.json]``
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import resource
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import torch

from sonardet.detect.sasa.ops import (
    ball_query,
    ball_query_shells,
    furthest_point_sample,
    grouping_operation,
    index_points,
    iou_bev_rotated,
    nms_bev_rotated,
    semantic_furthest_point_sample,
)

RADII = [0.4, 0.8, 1.2]
NSAMPLES = [16, 16, 32]


@contextmanager
def fps_path(path: str):
    """FPS on the compiled CPU kernel (``"compiled"``) or the Triton kernel on CUDA (``"triton"``), the
    default of their device, or on the PyTorch loop (``"torch"``: both switched off)."""
    from sonardet.detect.sasa.ops import gpu_kernels, sampling

    saved = sampling.kernels, gpu_kernels.AVAILABLE
    if path == "torch":
        sampling.kernels, gpu_kernels.AVAILABLE = None, False
    try:
        yield
    finally:
        sampling.kernels, gpu_kernels.AVAILABLE = saved


def gpu_available() -> bool:
    """Whether the Triton FPS kernel can run (Triton imported)."""
    from sonardet.detect.sasa.ops import gpu_kernels

    return gpu_kernels.AVAILABLE


def seabed_cloud(batch: int, n: int, seed: int = 0) -> torch.Tensor:
    """(B, N, 3) float32 synthetic seabed points in a 40 m x 40 m window (metres)."""
    g = torch.Generator().manual_seed(seed)
    xy = (torch.rand(batch, n, 2, generator=g) - 0.5) * 40.0
    z = 0.3 * torch.sin(xy[..., 0] / 7.0) * torch.cos(xy[..., 1] / 5.0) + 0.02 * torch.randn(batch, n, generator=g)
    centres = (torch.rand(batch, 10, 2, generator=g) - 0.5) * 36.0
    d2 = ((xy[:, :, None, :] - centres[:, None, :, :]) ** 2).sum(-1)
    z = z + (1.5 * torch.exp(-d2 / 0.5)).sum(-1)
    return torch.cat([xy, z[..., None]], dim=-1).contiguous()


def clustered_boxes(k: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """k boxes [x,y,z,l,w,h,yaw] jittered around 25 objects, and scores."""
    g = torch.Generator().manual_seed(seed)
    obj = torch.cat([(torch.rand(25, 2, generator=g) - 0.5) * 36, torch.zeros(25, 1),
                     0.75 + 1.4 * torch.rand(25, 3, generator=g), (torch.rand(25, 1, generator=g) - 0.5) * 2 * math.pi], 1)
    which = torch.randint(0, 25, (k,), generator=g)
    boxes = obj[which].clone()
    boxes[:, :3] += 0.3 * torch.randn(k, 3, generator=g)
    boxes[:, 3:6] *= 1 + 0.1 * torch.randn(k, 3, generator=g)
    boxes[:, 6] += 0.3 * torch.randn(k, generator=g)
    return boxes, torch.rand(k, generator=g)


def timeit(fn, device: torch.device, repeat: int) -> float:
    """Best-of-``repeat`` wall time in seconds (after one warm-up call)."""
    fn()
    best = float("inf")
    for _ in range(repeat):
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        fn()
        if device.type == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t0)
    return best


def _peak_mb() -> float:
    """Peak resident set size of this process in MB (VmHWM, else ru_maxrss)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _reset_peak() -> None:
    try:  # Linux >= 4.0: reset the peak-RSS counter to the current RSS
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


def _mem_probe(args):
    """Child process: peak RSS growth (MB) of one ball-query call on CPU."""
    batch, n, m, shells, method, threads = args
    torch.set_num_threads(threads)
    xyz = seabed_cloud(batch, n)
    q = xyz[:, :m].contiguous()
    _reset_peak()
    base = _peak_mb()
    if shells:
        ball_query_shells(RADII, NSAMPLES, xyz, q, dilated=True, method=method)
    else:
        ball_query(RADII[-1], NSAMPLES[-1], xyz, q, method=method)
    return _peak_mb() - base


def weighted_bn_rows(add, repeat: int) -> None:
    """The compact grouped MLP's weighted batch norm + ReLU (training), forward and forward + backward, on
    60,000 distinct (centre, neighbour) rows of 64 channels with random multiplicities: the fused Numba
    kernels (CPU float32) against the PyTorch composition, the same function."""
    from sonardet.detect.sasa.backbone import _FusedWeightedBatchNormReLU, _WeightedBatchNormReLU

    g = torch.Generator().manual_seed(0)
    rows, ch = 60_000, 64
    h = torch.randn(rows, ch, generator=g).requires_grad_()
    mult = torch.randint(1, 6, (rows,), generator=g)
    wn = mult.to(torch.float32) / float(mult.sum())
    gamma = torch.rand(ch, generator=g).requires_grad_()
    beta = torch.rand(ch, generator=g).requires_grad_()
    up = torch.randn(rows, ch, generator=g)
    for name, fn in (("fused", _FusedWeightedBatchNormReLU), ("torch", _WeightedBatchNormReLU)):
        def fwd():
            with torch.no_grad():
                fn.apply(h, wn, gamma, beta, 1e-5)

        def fwd_bwd():
            y, _, _ = fn.apply(h, wn, gamma, beta, 1e-5)
            (y * up).sum().backward()
            h.grad = gamma.grad = beta.grad = None

        add(f"weighted BN+ReLU fwd [{name}]", f"R={rows} C={ch}", timeit(fwd, torch.device("cpu"), repeat))
        add(f"weighted BN+ReLU fwd+bwd [{name}]", f"R={rows} C={ch}", timeit(fwd_bwd, torch.device("cpu"), repeat))
    # The backward kernel alone (no autograd, no forward), as a training step calls it.
    from sonardet.detect.sasa.ops import kernels

    nchunks, parallel = kernels.parallel_chunks(torch.get_num_threads()), kernels.run_parallel(rows * ch)
    hn, wnn, gn, bn = h.detach().numpy(), wn.numpy(), gamma.detach().numpy(), beta.detach().numpy()
    _, mean, var = kernels.weighted_bn_relu_forward(hn, wnn, gn, bn, 1e-5, nchunks, parallel)
    invstd = 1.0 / np.sqrt(var + 1e-5)
    upn = up.numpy()
    add("weighted BN+ReLU bwd [fused kernel]", f"R={rows} C={ch}",
        timeit(lambda: kernels.weighted_bn_relu_backward(upn, hn, wnn, mean, var, invstd, gn, bn, 1e-5, nchunks,
                                                         parallel), torch.device("cpu"), repeat))


def segment_max_rows(add, repeat: int) -> None:
    """The compact grouped MLP's max pooling, forward and forward + backward, on 60,000 rows of 64
    post-ReLU channels in segments of 1-32 rows: the fused Numba kernels (CPU float32) against
    ``torch.segment_reduce``, the same values and gradients."""
    from sonardet.detect.sasa.backbone import _FusedSegmentMax

    g = torch.Generator().manual_seed(0)
    lengths = torch.randint(1, 33, (3_600,), generator=g)
    rows, ch = int(lengths.sum()), 64
    h = torch.relu(torch.randn(rows, ch, generator=g)).requires_grad_()
    up = torch.randn(len(lengths), ch, generator=g)
    paths = (("fused", lambda x: _FusedSegmentMax.apply(x, lengths)),
             ("torch", lambda x: torch.segment_reduce(x, "max", lengths=lengths, axis=0, unsafe=True)))
    for name, fn in paths:
        def fwd():
            with torch.no_grad():
                fn(h)

        def fwd_bwd():
            (fn(h) * up).sum().backward()
            h.grad = None

        add(f"segment max fwd [{name}]", f"R={rows} C={ch}", timeit(fwd, torch.device("cpu"), repeat))
        add(f"segment max fwd+bwd [{name}]", f"R={rows} C={ch}", timeit(fwd_bwd, torch.device("cpu"), repeat))
    # The backward kernel alone (no autograd, no forward), as a training step calls it.
    from sonardet.detect.sasa.ops import kernels

    nchunks, parallel = kernels.parallel_chunks(torch.get_num_threads()), kernels.run_parallel(rows * ch)
    offsets = np.concatenate([[0], np.cumsum(lengths.numpy())]).astype(np.int64)
    hn = h.detach().numpy()
    out = kernels.segment_max_forward(hn, offsets, nchunks, parallel)
    upn = up.numpy()
    add("segment max bwd [fused kernel]", f"R={rows} C={ch}",
        timeit(lambda: kernels.segment_max_backward(upn, out, hn, offsets, nchunks, parallel), torch.device("cpu"),
               repeat))


def last_layer_rows(add, repeat: int) -> None:
    """A compact grouped MLP's last layer and its pooling, forward + backward through autograd, as a
    training step on the calling thread runs them: the weighted batch norm + ReLU and the segment max
    as one function (``[fused]``, `backbone.weighted_batch_norm_relu_max`) against the two functions
    one after the other (``[two steps]``, what ``FUSE_LAST_MAX = False`` runs); the same numbers.
    60,000 rows of 64 and 30,000 of 128 channels in segments of 1-32 rows."""
    from sonardet.detect.sasa import backbone

    for n_seg, ch in ((3_600, 64), (1_800, 128)):
        g = torch.Generator().manual_seed(ch)
        lengths = torch.randint(1, 33, (n_seg,), generator=g)
        rows = int(lengths.sum())
        counts = torch.randint(1, 4, (rows,), generator=g).float()
        group = backbone.GroupRows(point=torch.arange(rows),
                                   centre=torch.repeat_interleave(torch.arange(n_seg), lengths),
                                   weight=counts, lengths=lengths, total=int(counts.sum()))
        h = (torch.randn(rows, ch, generator=g) * 2).requires_grad_()
        bn = torch.nn.BatchNorm1d(ch)
        up = torch.randn(n_seg, ch, generator=g)
        default = backbone.FUSE_LAST_MAX
        try:
            for name, fuse in (("fused", True), ("two steps", False)):
                backbone.FUSE_LAST_MAX = fuse

                def fwd_bwd():
                    (backbone.weighted_batch_norm_relu_max(h, bn, group) * up).sum().backward()
                    h.grad = bn.weight.grad = bn.bias.grad = None

                add(f"last BN+ReLU+max fwd+bwd [{name}]", f"R={rows} C={ch}",
                    timeit(fwd_bwd, torch.device("cpu"), repeat))
        finally:
            backbone.FUSE_LAST_MAX = default


def training_batch_cloud(results: str) -> torch.Tensor:
    """(4, 8192, 3) the points of a DEFAULTS training batch: the first 4 scenes of the training split
    under `results`, prepared and sampled as SASA's training does (augmentation drawn from seed 0)."""
    from sonardet.detect.sasa import DEFAULTS, resolve_params
    from sonardet.detect.sasa.data import prepare_scene
    from sonardet.detect.sasa.trainer import _make_batch

    split = Path(results) / "splits" / "train.txt"
    if not split.is_file():
        raise SystemExit(f"{split}: no training split here; name the results folder of a run with --results")
    params = resolve_params({}, base=DEFAULTS)
    scenes = [prepare_scene(Path(results) / "scenes" / f"{sid}.npz", params) for sid in split.read_text().split()[:4]]
    return _make_batch(scenes, params, np.random.default_rng(0), torch.device("cpu"), True)["xyz"].contiguous()


def sampling_rows(add, repeat: int, results: str | None = None) -> None:
    """The compiled FPS and ball-query kernels at the DEFAULTS training step's shapes (batch 4: D-FPS
    8192 -> 2048, then D-FPS and S-FPS 2048 -> 512 and 512 -> 256; the first SA layer's three
    dilated shells, 0.3 / 0.6 / 1.0 m with 8 / 16 / 16 neighbours, around 2048 centres), CPU, best of
    ``repeat``; on the synthetic seabed cloud, or with `results` on a training batch of that run
    (:func:`training_batch_cloud`: points on the objects, after the ground filter, far denser)."""
    cpu = torch.device("cpu")
    xyz = seabed_cloud(4, 8192) if results is None else training_batch_cloud(results)
    for n, m in ((8192, 2048), (2048, 512), (512, 256)):
        x = xyz[:, :n].contiguous()
        logits = torch.randn(4, n, generator=torch.Generator().manual_seed(n))
        add("D-FPS [compiled]", f"B=4 {n}->{m}", timeit(lambda: furthest_point_sample(x, m), cpu, repeat))
        if n < 8192:
            add("S-FPS (gamma=1) [compiled]", f"B=4 {n}->{m}",
                timeit(lambda: semantic_furthest_point_sample(x, logits, m, 1.0), cpu, repeat))
    q = index_points(xyz, furthest_point_sample(xyz, 2048))
    add("ball_query_shells x3 dil. [compiled]", "B=4 N=8192 M=2048",
        timeit(lambda: ball_query_shells([0.3, 0.6, 1.0], [8, 16, 16], xyz, q, dilated=True, method="compiled"),
               cpu, repeat), "r=0.3/0.6/1.0 K=8/16/16")


def row_adder(device: torch.device, rows: list[dict]):
    """A function add(op, shape, seconds, note="") that appends a timing row to `rows` and prints it."""
    def add(op, shape, seconds, note=""):
        rows.append({"device": str(device), "op": op, "shape": shape, "ms": 1000 * seconds, "note": note})
        print(f"{str(device):6s} {op:34s} {shape:34s} {1000 * seconds:10.1f} ms  {note}", flush=True)
    return add


def run(device: torch.device, batches: list[int], repeat: int, rows: list[dict]) -> None:
    add = row_adder(device, rows)

    for batch in batches:
        xyz0 = seabed_cloud(batch, 16384).to(device)
        chain = [(16384, 4096), (4096, 1024), (1024, 512)]
        xyz = xyz0
        if device.type == "cpu":
            paths = ["compiled", "torch"]
        else:
            paths = ["triton", "torch"] if gpu_available() else ["torch"]
        for n, m in chain:
            xyz = xyz[:, :n].contiguous()
            logits = torch.randn(batch, n, device=device)
            for path in paths:
                with fps_path(path):
                    add(f"D-FPS [{path}]", f"B={batch} {n}->{m}",
                        timeit(lambda: furthest_point_sample(xyz, m), device, repeat))
                    add(f"S-FPS (gamma=1) [{path}]", f"B={batch} {n}->{m}",
                        timeit(lambda: semantic_furthest_point_sample(xyz, logits, m, 1.0), device, repeat))
        xyz = xyz0
        q = index_points(xyz, furthest_point_sample(xyz, 4096))
        # dense on CPU only at batch 2 (it is ~15x slower than tiled there; it is the CUDA default)
        methods = (["compiled", "tiled", "dense"] if batch <= 2 else ["compiled", "tiled"]) if device.type == "cpu" \
            else ["dense", "tiled"]
        for method in methods:
            add(f"ball_query r=1.2 K=32 [{method}]", f"B={batch} N=16384 M=4096",
                timeit(lambda: ball_query(1.2, 32, xyz, q, method=method), device, repeat))
            add(f"ball_query_shells x3 dil. [{method}]", f"B={batch} N=16384 M=4096",
                timeit(lambda: ball_query_shells(RADII, NSAMPLES, xyz, q, dilated=True, method=method), device, repeat),
                "r=0.4/0.8/1.2 K=16/16/32")
        idx = ball_query(1.2, 32, xyz, q)
        feats = torch.randn(batch, 64, 16384, device=device, requires_grad=True)

        def group_fwd_bwd():
            out = grouping_operation(feats, idx)
            out.sum().backward()
            feats.grad = None

        add("grouping fwd", f"B={batch} C=64 N=16384 M=4096 K=32",
            timeit(lambda: grouping_operation(feats.detach(), idx), device, repeat))
        add("grouping fwd+bwd", f"B={batch} C=64 N=16384 M=4096 K=32", timeit(group_fwd_bwd, device, repeat))

    if device.type == "cpu":
        weighted_bn_rows(add, repeat)
        segment_max_rows(add, repeat)
        last_layer_rows(add, repeat)
    boxes, scores = clustered_boxes(500)
    boxes, scores = boxes.to(device), scores.to(device)
    n_keep = len(nms_bev_rotated(boxes, scores, 0.1))
    add("nms_bev_rotated thr=0.1", "K=500 (25 clusters)",
        timeit(lambda: nms_bev_rotated(boxes, scores, 0.1), device, repeat), f"{n_keep} kept")
    add("nms_bev_rotated thr=0.01", "K=500 (25 clusters)",
        timeit(lambda: nms_bev_rotated(boxes, scores, 0.01), device, repeat))
    add("iou_bev_rotated", "500 x 500", timeit(lambda: iou_bev_rotated(boxes, boxes), device, repeat))
    big, big_s = clustered_boxes(4096, seed=1)
    big, big_s = big.to(device), big_s.to(device)
    add("nms_bev_rotated thr=0.1", "K=4096 (25 clusters)",
        timeit(lambda: nms_bev_rotated(big, big_s, 0.1), device, max(1, repeat // 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="batch 2 only, 1 repeat, no memory probe")
    ap.add_argument("--no-cuda", action="store_true")
    ap.add_argument("--cuda-only", action="store_true", help="only the CUDA rows (on a machine with a GPU)")
    ap.add_argument("--rows-only", action="store_true",
                    help="only the grouped MLP's row kernels (weighted batch norm, segment max, the two fused in the "
                         "last layer), CPU, --repeat times")
    ap.add_argument("--sampling-only", action="store_true",
                    help="only the compiled FPS and ball-query kernels at the DEFAULTS step's shapes, CPU, "
                         "--repeat times")
    ap.add_argument("--results", default=None,
                    help="with --sampling-only: time on a DEFAULTS training batch of this run's training scenes")
    ap.add_argument("--json", default=None, help="write the rows to this JSON file")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    batches = [2] if args.quick else [2, 8]
    repeat = 1 if args.quick else args.repeat
    rows: list[dict] = []
    print(f"torch {torch.__version__}, CPU threads {torch.get_num_threads()}")
    print(f"{'device':6s} {'op':34s} {'shape':34s} {'time':>13s}")
    if args.rows_only or args.sampling_only:
        add = row_adder(torch.device("cpu"), rows)
        if args.rows_only:
            weighted_bn_rows(add, args.repeat)
            segment_max_rows(add, args.repeat)
            last_layer_rows(add, args.repeat)
        if args.sampling_only:
            sampling_rows(add, args.repeat, args.results)
        batches = []
    elif args.cuda_only:
        batches = []
    else:
        run(torch.device("cpu"), batches, repeat, rows)
    if torch.cuda.is_available() and not args.no_cuda and not (args.rows_only or args.sampling_only):
        print(f"CUDA: {torch.cuda.get_device_name()}")
        run(torch.device("cuda"), [2, 8], args.repeat, rows)
    if not args.quick and batches:
        ctx = mp.get_context("spawn")
        for batch in batches:
            for shells in (False, True):
                for method in ("compiled", "tiled", "dense"):
                    with ctx.Pool(1) as pool:
                        mb = pool.map(_mem_probe, [(batch, 16384, 4096, shells, method, args.threads)])[0]
                    op = "ball_query_shells x3" if shells else "ball_query r=1.2 K=32"
                    rows.append({"device": "cpu", "op": f"peak RSS growth {op} [{method}]",
                                 "shape": f"B={batch} N=16384 M=4096", "MB": mb})
                    print(f"cpu    peak RSS growth {op} [{method}] B={batch} N=16384 M=4096: {mb:.0f} MB", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"torch": torch.__version__, "threads": args.threads, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    main()
