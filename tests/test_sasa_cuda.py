"""SASA on CUDA: the GPU paths of the point operators and the network against the CPU ones.

Skipped where no CUDA device is visible (CI, the reference laptop). On a machine with a GPU:
``PYTHONPATH=src python -m pytest -m cuda tests/test_sasa_cuda.py`` (``--noconftest`` where the
workflow's test dependencies are not installed: this module needs only torch, numpy, scipy, numba).

On CUDA, FPS and S-FPS run the Triton kernel (:mod:`sonardet.detect.sasa.ops.gpu_kernels`) where
Triton is installed, else the PyTorch loop; the ball query runs the dense PyTorch path, NMS and the
rotated IoU their PyTorch code. Indices must equal the CPU's (the compiled kernels, themselves tested
against the reference kernels' simulation in ``tests/test_sasa_ops.py``); float results agree to
float32 rounding. The network cannot be compared bit for bit (other GEMM kernels, atomics in the
backward), so the tests check that it learns on the GPU as it does on the CPU.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest
import torch

from sonardet.detect.sasa.ops import (
    ball_query,
    ball_query_shells,
    furthest_point_sample,
    grouping_operation,
    iou3d_rotated,
    iou_bev_rotated,
    nms_bev_rotated,
    semantic_furthest_point_sample,
    weighted_furthest_point_sample,
)

pytestmark = [pytest.mark.cuda,
              pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device visible")]

CUDA = torch.device("cuda")


def sonar_cloud(batch: int, n: int, seed: int, dtype=torch.float32) -> torch.Tensor:
    """(B, N, 3) seabed-like points far from the origin, with a raised patch (near-ties) and duplicates."""
    g = torch.Generator().manual_seed(seed)
    xy = torch.rand(batch, n, 2, generator=g, dtype=dtype) * 40.0
    z = (xy[..., 0] > 20).to(dtype) * 1.5 + 0.01 * torch.randn(batch, n, generator=g, dtype=dtype)
    xyz = torch.cat([xy, z[..., None]], -1) + torch.tensor([300.0, -200.0, -11.5], dtype=dtype)
    xyz[:, 100:200] = xyz[:, 100:101]
    return xyz


@pytest.fixture(params=["default", "torch_loop"])
def gpu_fps(request, monkeypatch):
    """FPS on CUDA through the Triton kernel (when Triton is there) and through the PyTorch loop."""
    from sonardet.detect.sasa.ops import gpu_kernels

    if request.param == "torch_loop":
        monkeypatch.setattr(gpu_kernels, "AVAILABLE", False)
    return request.param


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_fps_on_cuda_equals_cpu(gpu_fps, dtype):
    xyz = sonar_cloud(2, 6000, 1, dtype)
    logits = torch.randn(2, 6000, generator=torch.Generator().manual_seed(2), dtype=dtype) * 3
    for m in (1, 1500, 6000, 6100):
        assert torch.equal(furthest_point_sample(xyz.to(CUDA), m).cpu(), furthest_point_sample(xyz, m)), m
    for gamma in (1.0, 0.0):
        got = semantic_furthest_point_sample(xyz.to(CUDA), logits.to(CUDA), 1000, gamma).cpu()
        assert torch.equal(got, semantic_furthest_point_sample(xyz, logits, 1000, gamma)), gamma
    w = torch.sigmoid(logits)
    w[:, :50] = 0.0  # below the reference's clamp
    assert torch.equal(weighted_furthest_point_sample(xyz.to(CUDA), w.to(CUDA), 700).cpu(),
                       weighted_furthest_point_sample(xyz, w, 700))


def test_fps_ties_on_a_grid_on_cuda_equal_cpu(gpu_fps):
    """Integer grid points with duplicates: many equal distances, so the tie rule decides most picks."""
    g = torch.Generator().manual_seed(12)
    xyz = torch.randint(0, 6, (3, 2000, 3), generator=g).to(torch.float32)
    w = torch.randint(1, 4, (3, 2000), generator=g).to(torch.float32) / 3
    for m in (50, 216, 400):
        assert torch.equal(furthest_point_sample(xyz.to(CUDA), m).cpu(), furthest_point_sample(xyz, m)), m
        assert torch.equal(weighted_furthest_point_sample(xyz.to(CUDA), w.to(CUDA), m).cpu(),
                           weighted_furthest_point_sample(xyz, w, m)), m


def test_fps_study_sizes_on_cuda_equal_cpu(gpu_fps):
    """The study preset's chain (batch 8: 16384 -> 4096 -> 1024 -> 512) picks what the CPU picks."""
    xyz = sonar_cloud(8, 16384, 3)
    for n, m in ((16384, 4096), (4096, 1024), (1024, 512)):
        x = xyz[:, :n].contiguous()
        logits = torch.randn(8, n, generator=torch.Generator().manual_seed(n))
        assert torch.equal(furthest_point_sample(x.to(CUDA), m).cpu(), furthest_point_sample(x, m))
        got = semantic_furthest_point_sample(x.to(CUDA), logits.to(CUDA), m).cpu()
        assert torch.equal(got, semantic_furthest_point_sample(x, logits, m))


def test_triton_kernel_is_what_runs_on_cuda(monkeypatch):
    from sonardet.detect.sasa.ops import gpu_kernels, sampling

    if not gpu_kernels.AVAILABLE:
        pytest.skip("Triton is not installed: FPS runs the PyTorch loop on CUDA")

    def no_loop(*args):
        raise AssertionError("the PyTorch loop ran")

    monkeypatch.setattr(sampling, "_fps_torch", no_loop)
    xyz = sonar_cloud(2, 3000, 4).to(CUDA)
    assert furthest_point_sample(xyz, 300).shape == (2, 300)
    # larger clouds than one program holds fall back to the loop
    assert not gpu_kernels.usable(torch.zeros(1, gpu_kernels.MAX_POINTS + 1, 3, device=CUDA), None)
    bad = xyz.clone()
    bad[0, 7, 2] = math.inf
    assert not gpu_kernels.usable(bad, None)


@pytest.mark.parametrize("dilated", [False, True])
def test_ball_query_on_cuda_equals_cpu(dilated):
    xyz = sonar_cloud(2, 8000, 5)
    q = xyz[:, ::8].contiguous()
    radii, ns = [0.4, 0.8, 1.2], [16, 16, 32]
    cpu = ball_query_shells(radii, ns, xyz, q, dilated=dilated)
    gpu = ball_query_shells(radii, ns, xyz.to(CUDA), q.to(CUDA), dilated=dilated)
    for (c_cnt, c_idx), (g_cnt, g_idx) in zip(cpu, gpu):
        assert torch.equal(g_cnt.cpu(), c_cnt) and torch.equal(g_idx.cpu(), c_idx)
    cnt, idx = ball_query(1.2, 32, xyz.to(CUDA), q.to(CUDA), return_count=True)
    c_cnt, c_idx = ball_query(1.2, 32, xyz, q, return_count=True)
    assert torch.equal(cnt.cpu(), c_cnt) and torch.equal(idx.cpu(), c_idx)


def test_grouping_on_cuda_equals_cpu():
    g = torch.Generator().manual_seed(6)
    feats = torch.randn(2, 16, 500, generator=g, dtype=torch.float64, requires_grad=True)
    idx = torch.randint(0, 500, (2, 64, 8), generator=g)
    up = torch.randn(2, 16, 64, 8, generator=g, dtype=torch.float64)
    out = grouping_operation(feats, idx)
    (out * up).sum().backward()
    f_gpu = feats.detach().to(CUDA).requires_grad_()
    out_gpu = grouping_operation(f_gpu, idx.to(CUDA))
    (out_gpu * up.to(CUDA)).sum().backward()
    assert torch.equal(out_gpu.detach().cpu(), out.detach())
    torch.testing.assert_close(f_gpu.grad.cpu(), feats.grad)


def test_rotated_iou_and_nms_on_cuda_equal_cpu():
    rng = np.random.default_rng(8)
    k = 400
    centres = rng.uniform(-10, 10, (25, 2))
    xy = centres[rng.integers(0, 25, k)] + rng.normal(0, 0.4, (k, 2))
    boxes = np.c_[xy, rng.uniform(-1, 1, k), rng.uniform(0.5, 3, (k, 3)), rng.uniform(-math.pi, math.pi, k)]
    scores = rng.uniform(size=k)
    b, s = torch.from_numpy(boxes), torch.from_numpy(scores)
    torch.testing.assert_close(iou_bev_rotated(b.to(CUDA), b.to(CUDA)).cpu(), iou_bev_rotated(b, b))
    torch.testing.assert_close(iou3d_rotated(b.to(CUDA), b.to(CUDA)).cpu(), iou3d_rotated(b, b))
    for thr in (0.01, 0.1, 0.5):
        assert nms_bev_rotated(b.to(CUDA), s.to(CUDA), thr).cpu().tolist() == nms_bev_rotated(b, s, thr).tolist()


def test_weighted_batch_norm_and_segment_max_on_cuda_agree_with_cpu():
    """The grouped MLP's normalisation and pooling: CPU fused kernels vs the PyTorch formulation on CUDA."""
    from sonardet.detect.sasa.backbone import GroupRows, segment_max, weighted_batch_norm_relu

    g = torch.Generator().manual_seed(9)
    lengths = torch.randint(1, 17, (500,), generator=g)
    rows, ch = int(lengths.sum()), 32
    h = torch.randn(rows, ch, generator=g) * 2 + 0.5
    mult = torch.randint(1, 5, (rows,), generator=g)
    up = torch.randn(rows, ch, generator=g)
    up_max = torch.randn(len(lengths), ch, generator=g)
    results = []
    for dev in (torch.device("cpu"), CUDA):
        bn = torch.nn.BatchNorm1d(ch).to(dev)
        with torch.no_grad():
            bn.weight.copy_(torch.linspace(0.5, 1.5, ch))
            bn.bias.copy_(torch.linspace(-0.2, 0.2, ch))
        x = h.to(dev, copy=True).requires_grad_()
        m = mult.to(dev)
        y = weighted_batch_norm_relu(x, bn, GroupRows(None, None, m, lengths.to(dev), int(m.sum())))
        pooled = segment_max(y, lengths.to(dev))
        ((y * up.to(dev)).sum() + (pooled * up_max.to(dev)).sum()).backward()
        results.append([t.detach().cpu() for t in (y, pooled, x.grad, bn.weight.grad, bn.bias.grad,
                                                    bn.running_mean, bn.running_var)])
    for c, gpu in zip(*results):
        torch.testing.assert_close(gpu, c, rtol=1e-4, atol=1e-5)



def test_training_on_cuda_learns_and_the_model_runs_on_cpu(tmp_path):
    """The CPU overfitting test (tests/test_sasa_model.py) on the GPU: a tiny model fits two small
    scenes; the model file it writes detects on the GPU and on a CPU-only machine."""
    from test_sasa_model import TINY, make_scene

    from sonardet.detect.sasa import infer, resolve_params, train
    from sonardet.detect.sasa.trainer import evaluate_scenes

    paths = [make_scene(tmp_path, "o0", 10, ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]),
             make_scene(tmp_path, "o1", 11, ["tetrapod_s", "tetrapod_b", "reef_cone", "reef_ring"])]
    params = {**TINY, "epochs": 200, "lr": 0.01, "batch_size": 2, "aug_rotation_rad": 0.0, "aug_flip_x": False,
              "aug_flip_y": False, "aug_object_prob": 0.0, "aug_scale": [1.0, 1.0], "score_thresh": 0.05,
              "n_points": 1024, "sa_npoints": [256, 128, 64]}
    summary = train(paths, [], params, tmp_path / "run", device="cuda", resume=False)
    assert summary["steps"] == 200
    for device in ("cuda", "cpu"):
        dets, timing = infer(tmp_path / "run" / "model.pt", paths, dict(params), device=device)
        assert timing["device"].startswith(device)
        m = evaluate_scenes(dets, paths, resolve_params(params), dist_thresholds_m=(0.5, 1.0))
        assert m["mAP"]["1.0"] >= 0.9, (device, m["mAP"])
        assert m["mAP"]["0.5"] >= 0.75, (device, m["mAP"])


def test_study_preset_trains_and_detects_on_cuda(tmp_path):
    """The study's network (16384 raw points, batch 8, 2.6 M parameters) takes training steps and
    detects on the GPU; its loss is finite and falls on a fixed pair of scenes."""
    from test_sasa_model import CLASSES, make_scene

    from sonardet.detect.sasa import STUDY, infer, resolve_params, train

    scenes = [make_scene(tmp_path, f"s{i:04d}", i, CLASSES, density=90.0) for i in range(2)]
    params = resolve_params({"classes": CLASSES, "batch_size": 2, "epochs": 6, "val_every_epochs": 0,
                             "progress": False, "aug_object_prob": 0.0}, STUDY)
    summary = train(scenes, [], params, tmp_path / "study", device="cuda")
    assert summary["steps"] == 6 and summary["n_parameters"] > 2_000_000
    with open(tmp_path / "study" / "loss.csv") as fh:
        losses = [float(row["loss"]) for row in csv.DictReader(fh)]
    assert all(math.isfinite(v) for v in losses) and min(losses[-2:]) < losses[0], losses
    dets, timing = infer(tmp_path / "study" / "model.pt", scenes, params={"progress": False}, device="cuda")
    assert set(dets) == {"s0000", "s0001"} and timing["device"].startswith("cuda")
