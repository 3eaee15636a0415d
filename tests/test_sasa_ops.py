"""Tests of the SASA point operators against slow, obviously-correct references.

FPS and the ball query run on CPU through compiled kernels (Numba) by default; every equality test
runs on the compiled path and on the PyTorch paths (the CUDA and fallback implementations). The FPS
reference simulates the reference CUDA kernel thread by thread (strided scans and the
shared-memory tree reduction), so tie-breaking is checked, not just the distance rule. The ball
query reference is the kernel's per-query loop. The rotated IoU reference is a scalar numpy
Sutherland-Hodgman clipper, itself checked against Monte Carlo areas.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sonardet.detect.sasa.ops import (
    GroupAll,
    QueryAndGroup,
    ball_query,
    ball_query_dilated,
    ball_query_shells,
    bev_corners,
    fps_block_size,
    furthest_point_sample,
    gather_operation,
    grouping_operation,
    index_points,
    iou3d_rotated,
    iou_bev_rotated,
    nms_bev_rotated,
    overlap_bev_rotated,
    semantic_furthest_point_sample,
    weighted_furthest_point_sample,
)

torch.set_num_threads(2)


@pytest.fixture(params=["compiled", "plain", "two_level"])
def argmax_mode(request, monkeypatch):
    """Run FPS tests on the compiled kernel and on both argmax paths of the PyTorch loop (the
    two-level one is used for large B * N)."""
    from sonardet.detect.sasa.ops import sampling

    if request.param == "compiled":
        assert sampling.kernels is not None, "the compiled kernels (Numba) should be available"
    else:
        monkeypatch.setattr(sampling, "kernels", None)  # the PyTorch loop, as on CUDA
    monkeypatch.setattr(sampling, "_HIER_MIN", 0 if request.param == "two_level" else 1 << 62)
    return request.param


# ------------------------------------------------------------------------------------------------
# slow references
# ------------------------------------------------------------------------------------------------
def ref_fps_kernel(xyz: np.ndarray, m: int, weights: np.ndarray | None = None) -> list[int]:
    """Thread-by-thread simulation of the reference CUDA (weighted) FPS kernel for one cloud (float32)."""
    xyz = np.asarray(xyz, dtype=np.float32)
    n = len(xyz)
    block = max(min(2 ** int(math.log(n) / math.log(2.0)), 1024), 1)
    temp = np.full(n, 1e10, dtype=np.float32)
    w_min = np.float32(1e-12)
    idxs = []
    old = 0
    for j in range(m):
        if weights is None and j == 0:
            idxs.append(0)
            continue
        best = [np.float32(-1.0)] * block
        besti = [0] * block
        x1, y1, z1 = xyz[old]
        for tid in range(block):
            for k in range(tid, n, block):
                if weights is not None and j == 0:
                    d2 = weights[k]
                else:
                    x2, y2, z2 = xyz[k]
                    d = (x2 - x1) * (x2 - x1) + (y2 - y1) * (y2 - y1) + (z2 - z1) * (z2 - z1)
                    d = min(d, temp[k])
                    temp[k] = d
                    d2 = d if weights is None else d * max(weights[k], w_min)
                if d2 > best[tid]:
                    best[tid], besti[tid] = d2, k
        s = block // 2
        while s >= 1:
            for tid in range(s):
                v1, v2 = best[tid], best[tid + s]
                i1, i2 = besti[tid], besti[tid + s]
                best[tid] = max(v1, v2)
                besti[tid] = i2 if v2 > v1 else i1
            s //= 2
        old = besti[0]
        idxs.append(old)
    return idxs


def ref_ball_query(xyz, new_xyz, r_in, r_out, nsample):
    """The reference kernel's per-query loop (float32), cyclic padding, zero-filled empty balls."""
    xyz = np.asarray(xyz, np.float32)
    new_xyz = np.asarray(new_xyz, np.float32)
    B, M = new_xyz.shape[:2]
    idx = np.zeros((B, M, nsample), np.int64)
    cnt = np.zeros((B, M), np.int64)
    r_out2 = np.float32(r_out) * np.float32(r_out)
    r_in2 = None if r_in is None else np.float32(r_in) * np.float32(r_in)
    for b in range(B):
        for m in range(M):
            qx, qy, qz = new_xyz[b, m]
            c = 0
            for k in range(xyz.shape[1]):
                x, y, z = xyz[b, k]
                d2 = (qx - x) * (qx - x) + (qy - y) * (qy - y) + (qz - z) * (qz - z)
                if d2 < r_out2 and (r_in2 is None or d2 >= r_in2):
                    idx[b, m, c] = k
                    c += 1
                    if c >= nsample:
                        break
            cnt[b, m] = c
            l = 0
            while c < nsample:
                idx[b, m, c] = idx[b, m, l]
                l += 1
                c += 1
    return cnt, idx


def ref_corners(box):
    x, y, _, l, w, _, yaw = [float(v) for v in box]
    c, s = math.cos(yaw), math.sin(yaw)
    out = []
    for su, sv in [(1, 1), (-1, 1), (-1, -1), (1, -1)]:
        u, v = su * l / 2, sv * w / 2
        out.append((x + u * c - v * s, y + u * s + v * c))
    return out


def ref_clip_area(box_a, box_b) -> float:
    """Textbook scalar Sutherland-Hodgman: clip footprint b by the 4 edges of footprint a; shoelace."""
    poly = ref_corners(box_b)
    ca = ref_corners(box_a)
    for k in range(4):
        (ax, ay), (bx, by) = ca[k], ca[(k + 1) % 4]

        def side(p):
            return (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax)

        new = []
        for i in range(len(poly)):
            p, q = poly[i], poly[(i + 1) % len(poly)]
            sp, sq = side(p), side(q)
            if sp >= 0:
                new.append(p)
            if (sp >= 0) != (sq >= 0):
                t = sp / (sp - sq)
                new.append((p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])))
        poly = new
        if not poly:
            return 0.0
    area = 0.0
    for i in range(len(poly)):
        area += poly[i][0] * poly[(i + 1) % len(poly)][1] - poly[(i + 1) % len(poly)][0] * poly[i][1]
    return abs(area) / 2


def ref_iou_bev(a, b) -> float:
    inter = ref_clip_area(a, b)
    return inter / max(a[3] * a[4] + b[3] * b[4] - inter, 1e-8)


def random_boxes(rng, k, spread=3.0):
    xy = rng.uniform(-spread, spread, (k, 2))
    z = rng.uniform(-1, 1, (k, 1))
    lwh = rng.uniform(0.3, 3.0, (k, 3))
    yaw = rng.uniform(-math.pi, math.pi, (k, 1))
    return np.hstack([xy, z, lwh, yaw])


# ------------------------------------------------------------------------------------------------
# FPS / S-FPS
# ------------------------------------------------------------------------------------------------
def test_block_size_matches_reference_rule():
    assert [fps_block_size(n) for n in (1, 2, 3, 4, 7, 8, 1000, 1024, 1025, 16384)] == [
        1, 2, 2, 4, 4, 8, 512, 1024, 1024, 1024]


@pytest.mark.parametrize("n,m", [(37, 20), (130, 60), (8, 8)])
def test_dfps_matches_kernel_simulation_random(n, m, argmax_mode):
    rng = np.random.default_rng(n)
    xyz = rng.normal(size=(2, n, 3)).astype(np.float32)
    got = furthest_point_sample(torch.from_numpy(xyz), m)
    assert got.dtype == torch.int64 and got.shape == (2, m)
    for b in range(2):  # batch > 1: clouds sampled independently
        assert got[b].tolist() == ref_fps_kernel(xyz[b], m)


def test_dfps_tie_breaking_on_grid_with_duplicates(argmax_mode):
    # Integer grid: squared distances are exact integers, so ties are everywhere; plus duplicates.
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(np.arange(5), np.arange(4), np.arange(3), indexing="ij"), -1).reshape(-1, 3)
    xyz = np.concatenate([g, g[rng.integers(0, len(g), 25)]]).astype(np.float32)
    xyz = xyz[rng.permutation(len(xyz))]  # N = 85: block of 64 threads, some scan 2 indices
    m = 80  # more than the 60 distinct locations: exhausted distances must pick like the kernel
    got = furthest_point_sample(torch.from_numpy(xyz)[None], m)[0].tolist()
    want = ref_fps_kernel(xyz, m)
    assert got == want
    assert want[-1] == 0  # after exhaustion the kernel returns index 0


def test_dfps_edge_cases(argmax_mode):
    # a single point
    assert furthest_point_sample(torch.zeros(3, 1, 3), 4).tolist() == [[0] * 4] * 3
    # npoint == 0
    assert furthest_point_sample(torch.rand(2, 5, 3), 0).shape == (2, 0)
    # fewer points than samples: FPS order of all points, then repeated cyclically
    xyz = torch.rand(2, 6, 3)
    idx = furthest_point_sample(xyz, 15)
    for b in range(2):
        first = idx[b, :6].tolist()
        assert sorted(first) == list(range(6)) and first[0] == 0
        assert first == ref_fps_kernel(xyz[b].numpy(), 6)
        assert idx[b].tolist() == [first[j % 6] for j in range(15)]
    # all points identical
    assert furthest_point_sample(torch.ones(1, 9, 3), 5).tolist() == [[0] * 5]
    with pytest.raises(ValueError):
        furthest_point_sample(torch.zeros(1, 0, 3), 2)
    with pytest.raises(ValueError):
        furthest_point_sample(torch.zeros(4, 3), 2)


def test_dfps_float64_and_samples_are_distinct_when_possible():
    xyz = torch.rand(3, 300, 3, dtype=torch.float64)
    idx = furthest_point_sample(xyz, 100)
    assert all(len(set(r)) == 100 for r in idx.tolist())


def test_weighted_fps_matches_kernel_simulation_with_tied_weights(argmax_mode):
    rng = np.random.default_rng(3)
    xyz = rng.integers(0, 6, size=(2, 70, 3)).astype(np.float32)  # grid coordinates with duplicates
    w = rng.choice(np.array([0.0, 0.25, 0.5, 1.0], np.float32), size=(2, 70))
    got = weighted_furthest_point_sample(torch.from_numpy(xyz), torch.from_numpy(w), 40)
    for b in range(2):
        assert got[b].tolist() == ref_fps_kernel(xyz[b], 40, w[b])


def test_sfps_matches_kernel_simulation_from_logits(argmax_mode):
    rng = np.random.default_rng(4)
    xyz = rng.normal(size=(2, 90, 3)).astype(np.float32)
    logits = rng.normal(scale=3, size=(2, 90)).astype(np.float32)
    gamma = 2.0
    w = (torch.sigmoid(torch.from_numpy(logits)) ** gamma).numpy()
    got = semantic_furthest_point_sample(torch.from_numpy(xyz), torch.from_numpy(logits), 30, gamma)
    for b in range(2):
        want = ref_fps_kernel(xyz[b], 30, w[b])
        assert got[b].tolist() == want
        assert want[0] == int(np.argmax(w[b]))  # S-FPS starts at the highest-score point


def test_sfps_gamma_zero_equals_dfps(argmax_mode):
    xyz = torch.randn(3, 500, 3)
    scores = torch.randn(3, 500) * 4
    assert torch.equal(semantic_furthest_point_sample(xyz, scores, 128, gamma=0.0), furthest_point_sample(xyz, 128))
    assert torch.equal(semantic_furthest_point_sample(xyz, scores, 700, gamma=0.0), furthest_point_sample(xyz, 700))


def test_sfps_prefers_high_score_points():
    g = torch.Generator().manual_seed(5)
    xyz = torch.rand(1, 400, 3, generator=g) * torch.tensor([10.0, 10.0, 1.0])
    fg = torch.zeros(400, dtype=torch.bool)
    fg[torch.randperm(400, generator=g)[:100]] = True  # 25 % foreground, interleaved in space
    logits = torch.where(fg, 4.0, -4.0)[None]
    s_idx = semantic_furthest_point_sample(xyz, logits, 40, gamma=1.0)[0]
    d_idx = furthest_point_sample(xyz, 40)[0]
    assert fg[s_idx[0]]
    assert fg[s_idx].float().mean() > 0.9
    assert fg[d_idx].float().mean() < 0.5


def _torch_fps(monkeypatch, fn, *args):
    """``fn(*args)`` through the PyTorch loop (the compiled kernel switched off)."""
    from sonardet.detect.sasa.ops import sampling

    with monkeypatch.context() as m:
        m.setattr(sampling, "kernels", None)
        return fn(*args)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_compiled_fps_equals_torch_loop_on_large_clouds(monkeypatch, dtype):
    # Large enough for the block skipping to matter (many blocks, most of them skipped late on):
    # clustered sonar-like clouds with flat patches (near-ties) and an offset far from the origin.
    g = torch.Generator().manual_seed(11)
    xy = torch.rand(2, 6000, 2, generator=g, dtype=dtype) * 40.0
    z = (xy[..., 0] > 20).to(dtype) * 1.5 + 0.01 * torch.randn(2, 6000, generator=g, dtype=dtype)
    xyz = torch.cat([xy, z[..., None]], -1) + torch.tensor([300.0, -200.0, -11.5], dtype=dtype)
    xyz[:, 100:200] = xyz[:, 100:101]  # duplicates
    logits = torch.randn(2, 6000, generator=g, dtype=dtype) * 3
    for m in (1, 1500, 6000, 6100):
        assert torch.equal(furthest_point_sample(xyz, m), _torch_fps(monkeypatch, furthest_point_sample, xyz, m))
    for gamma in (1.0, 0.0):
        got = semantic_furthest_point_sample(xyz, logits, 1000, gamma)
        assert torch.equal(got, _torch_fps(monkeypatch, semantic_furthest_point_sample, xyz, logits, 1000, gamma))


def test_fps_nonfinite_falls_back_to_torch_loop(monkeypatch):
    xyz = torch.rand(1, 200, 3)
    xyz[0, 50, 1] = float("inf")
    assert torch.equal(furthest_point_sample(xyz, 40), _torch_fps(monkeypatch, furthest_point_sample, xyz, 40))


# ------------------------------------------------------------------------------------------------
# ball query
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["compiled", "tiled", "dense"])
def test_ball_query_matches_reference_loop(method):
    rng = np.random.default_rng(7)
    xyz = rng.uniform(0, 4, size=(2, 300, 3)).astype(np.float32)
    xyz[:, :, 2] *= 0.3
    new_xyz = np.concatenate([xyz[:, :40], rng.uniform(-1, 5, size=(2, 20, 3)).astype(np.float32)], 1)
    x, q = torch.from_numpy(xyz), torch.from_numpy(new_xyz)
    for r, ns in [(0.3, 8), (0.6, 16), (1.2, 32)]:
        cnt, idx = ball_query(r, ns, x, q, chunk_size=7, return_count=True, method=method)
        rc, ri = ref_ball_query(xyz, new_xyz, None, r, ns)
        np.testing.assert_array_equal(cnt.numpy(), rc)
        np.testing.assert_array_equal(idx.numpy(), ri)
    cnt, idx = ball_query_dilated(0.4, 0.9, 12, x, q, chunk_size=5, return_count=True, method=method)
    rc, ri = ref_ball_query(xyz, new_xyz, 0.4, 0.9, 12)
    np.testing.assert_array_equal(cnt.numpy(), rc)
    np.testing.assert_array_equal(idx.numpy(), ri)
    assert (rc == 0).any() and (rc == 12).any() and ((rc > 0) & (rc < 12)).any()


@pytest.mark.parametrize("method", ["auto", "tiled", "dense"])
def test_ball_query_boundaries_padding_and_empty(method):
    # points on a line at integer distances from the query: d < r strict, r_in <= d inclusive
    xyz = torch.tensor([[[3.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0], [2.0, 0, 0], [1.0, 0, 0]]])
    q = torch.tensor([[[0.0, 0, 0], [50.0, 50, 50]]])
    cnt, idx = ball_query(2.0, 5, xyz, q, return_count=True, method=method)
    assert cnt.tolist() == [[3, 0]]
    assert idx[0, 0].tolist() == [1, 2, 4, 1, 2]  # index order, then cyclic repetition
    assert idx[0, 1].tolist() == [0] * 5  # no neighbour: zeros, count 0
    cnt, idx = ball_query_dilated(1.0, 3.0, 4, xyz, q, return_count=True, method=method)
    assert cnt.tolist() == [[3, 0]] and idx[0, 0].tolist() == [1, 3, 4, 1]
    one = ball_query(1.5, 4, xyz, q[:, :1], method=method)  # single hit -> "fill with the first found index"
    assert one[0, 0].tolist() == [1, 2, 4, 1]
    # a single point, duplicates, more samples than points
    cnt, idx = ball_query(0.1, 6, torch.zeros(1, 1, 3), torch.zeros(1, 3, 3), return_count=True, method=method)
    assert cnt.tolist() == [[1, 1, 1]] and idx.unique().tolist() == [0]


def test_ball_query_shells_equal_individual_queries():
    g = torch.Generator().manual_seed(2)
    xyz = torch.rand(2, 1000, 3, generator=g) * torch.tensor([14.0, 14.0, 2.0])
    q = index_points(xyz, furthest_point_sample(xyz, 128))
    radii, ns = [0.4, 0.8, 1.6], [8, 16, 32]
    for dilated in (False, True):
        shells = ball_query_shells(radii, ns, xyz, q, dilated=dilated, chunk_size=20)
        dense = ball_query_shells(radii, ns, xyz, q, dilated=dilated, method="dense", max_pairs=5000)
        tiny = ball_query_shells(radii, ns, xyz, q, dilated=dilated, chunk_size=64, max_pairs=700, method="tiled")
        assert all(torch.equal(c1, c2) and torch.equal(i1, i2) for (c1, i1), (c2, i2) in zip(tiny, dense))
        compiled = ball_query_shells(radii, ns, xyz, q, dilated=dilated, method="compiled")
        assert all(torch.equal(c1, c2) and torch.equal(i1, i2) for (c1, i1), (c2, i2) in zip(compiled, dense))
        prev = 0.0
        for (cnt, idx), (dc, di), r, n in zip(shells, dense, radii, ns):
            if dilated:
                c1, i1 = ball_query_dilated(prev, r, n, xyz, q, return_count=True)
                prev = r
            else:
                c1, i1 = ball_query(r, n, xyz, q, return_count=True)
            assert torch.equal(cnt, c1) and torch.equal(idx, i1)
            assert torch.equal(cnt, dc) and torch.equal(idx, di)


@pytest.mark.parametrize("dilated", [False, True])
def test_compiled_ball_query_equals_tiled_on_large_clouds(dilated):
    # the SA1 / vote shapes: many centres, hits both far below and above nsample, an offset origin
    g = torch.Generator().manual_seed(8)
    xyz = torch.rand(2, 8000, 3, generator=g) * torch.tensor([40.0, 40.0, 2.0]) + torch.tensor([5e3, -3e3, -11.5])
    xyz[:, 10:40] = xyz[:, 10:11]  # duplicates
    q = index_points(xyz, furthest_point_sample(xyz, 1000))
    q = torch.cat([q, q[:, :50] + 0.37, torch.full((2, 3, 3), 9e3)], 1)  # off-sample and far-away centres
    radii, ns = [0.3, 0.6, 1.0], [8, 16, 16]
    a = ball_query_shells(radii, ns, xyz, q, dilated=dilated, method="compiled")
    b = ball_query_shells(radii, ns, xyz, q, dilated=dilated, method="tiled")
    assert all(torch.equal(c1, c2) and torch.equal(i1, i2) for (c1, i1), (c2, i2) in zip(a, b))
    assert any(bool((c == 0).any()) for c, _ in a) and any(bool((c == n).any()) for (c, _), n in zip(a, ns))


def test_compiled_ball_query_sparse_cloud_over_large_extent():
    # tiny radius over a huge extent: the grid is capped at a few columns per point, still exact
    g = torch.Generator().manual_seed(9)
    xyz = torch.rand(1, 500, 3, generator=g, dtype=torch.float64) * 1e5
    xyz[0, 1:6] = xyz[0, 0] + 0.01 * torch.arange(1, 6, dtype=torch.float64)[:, None]
    q = xyz[:, :20].clone()
    a = ball_query_shells([0.02, 0.05], [3, 4], xyz, q, method="compiled")
    b = ball_query_shells([0.02, 0.05], [3, 4], xyz, q, method="tiled")
    assert all(torch.equal(c1, c2) and torch.equal(i1, i2) for (c1, i1), (c2, i2) in zip(a, b))
    assert int(a[1][0][0, 0]) == 3  # itself and the points at 0.017 and 0.035 m
    with pytest.raises(ValueError):
        bad = xyz.clone()
        bad[0, 3, 0] = float("nan")
        ball_query(0.1, 4, bad, q, method="compiled")


def test_ball_query_nonfinite_points_fall_back_without_pruning():
    xyz = torch.rand(1, 50, 3)
    xyz[0, 7] = float("nan")
    q = xyz[:, :10].clone()
    cnt, idx = ball_query(0.5, 8, xyz, q, chunk_size=3, return_count=True)
    rc, ri = ref_ball_query(xyz.numpy(), q.numpy(), None, 0.5, 8)
    assert np.array_equal(cnt.numpy(), rc) and np.array_equal(idx.numpy(), ri)


# ------------------------------------------------------------------------------------------------
# gather / grouping / QueryAndGroup
# ------------------------------------------------------------------------------------------------
def test_gather_and_grouping_values():
    f = torch.arange(2 * 3 * 5, dtype=torch.float32).view(2, 3, 5)
    idx = torch.tensor([[4, 0], [1, 1]])
    out = gather_operation(f, idx)
    assert out.shape == (2, 3, 2)
    assert out[1, 2].tolist() == [f[1, 2, 1].item()] * 2 and out[0, 1].tolist() == [f[0, 1, 4].item(), f[0, 1, 0].item()]
    gidx = torch.tensor([[[0, 1, 2], [4, 4, 4]], [[3, 2, 1], [0, 0, 0]]])
    g = grouping_operation(f, gidx)
    assert g.shape == (2, 3, 2, 3)
    for b in range(2):
        for c in range(3):
            for m in range(2):
                for k in range(3):
                    assert g[b, c, m, k] == f[b, c, gidx[b, m, k]]


def test_grouping_and_gather_gradcheck():
    f = torch.randn(2, 3, 6, dtype=torch.float64, requires_grad=True)
    gidx = torch.randint(0, 6, (2, 4, 3))  # repeated indices: gradients accumulate
    assert torch.autograd.gradcheck(lambda t: grouping_operation(t, gidx), (f,))
    idx = torch.randint(0, 6, (2, 5))
    assert torch.autograd.gradcheck(lambda t: gather_operation(t, idx), (f,))


def test_query_and_group():
    torch.manual_seed(0)
    xyz = torch.rand(2, 60, 3, dtype=torch.float64)
    q = xyz[:, :10].clone()
    feats = torch.randn(2, 4, 60, dtype=torch.float64, requires_grad=True)
    grouper = QueryAndGroup(0.3, 8)
    cnt, out = grouper(xyz, q, feats)
    assert out.shape == (2, 7, 10, 8) and cnt.shape == (2, 10)
    _, idx = ball_query(0.3, 8, xyz, q, return_count=True)
    rel = index_points(xyz, idx) - q[:, :, None, :]
    assert torch.allclose(out[:, :3], rel.permute(0, 3, 1, 2))
    assert (out[:, :3].norm(dim=1) < 0.3).all()  # queries are data points: every ball has a hit
    assert torch.equal(out[:, 3:], grouping_operation(feats, idx))
    _, norm = QueryAndGroup(0.3, 8, normalize_xyz=True)(xyz, q, feats)
    assert torch.allclose(norm[:, :3] * 0.3, out[:, :3])
    cnt_d, dil = QueryAndGroup(0.3, 8, radius_in=0.1)(xyz, q, None)
    assert dil.shape == (2, 3, 10, 8)
    assert torch.equal(cnt_d, ball_query_dilated(0.1, 0.3, 8, xyz, q, return_count=True)[0])
    _, nofeat = QueryAndGroup(0.3, 8, use_xyz=False)(xyz, q, feats)
    assert nofeat.shape == (2, 4, 10, 8)
    small = feats[:, :2, :20].detach().clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: grouper(xyz[:, :20], q[:, :4], t)[1], (small,))
    cnt_all, all_f = GroupAll()(xyz, None, feats)
    assert all_f.shape == (2, 7, 1, 60) and cnt_all.tolist() == [[1], [1]]


# ------------------------------------------------------------------------------------------------
# rotated IoU / NMS
# ------------------------------------------------------------------------------------------------
def test_reference_clipper_agrees_with_monte_carlo():
    rng = np.random.default_rng(11)
    boxes = random_boxes(rng, 8, spread=1.0)
    pts = rng.uniform(-4, 4, size=(200_000, 2))

    def inside(box, p):
        c, s = math.cos(box[6]), math.sin(box[6])
        d = p - box[:2]
        u = d[:, 0] * c + d[:, 1] * s
        v = -d[:, 0] * s + d[:, 1] * c
        return (np.abs(u) <= box[3] / 2) & (np.abs(v) <= box[4] / 2)

    for a, b in zip(boxes[:4], boxes[4:]):
        mc = (inside(a, pts) & inside(b, pts)).mean() * 64.0
        assert abs(ref_clip_area(a, b) - mc) < 0.05
        assert abs(ref_clip_area(a, b) - ref_clip_area(b, a)) < 1e-12


def test_iou_bev_rotated_matches_reference_random():
    rng = np.random.default_rng(12)
    a = random_boxes(rng, 40)
    b = random_boxes(rng, 30)
    want = np.array([[ref_iou_bev(x, y) for y in b] for x in a])
    assert (want > 0).mean() > 0.2  # many overlapping pairs are exercised
    got64 = iou_bev_rotated(torch.from_numpy(a), torch.from_numpy(b), pair_chunk=97).numpy()
    np.testing.assert_allclose(got64, want, atol=1e-10)
    got32 = iou_bev_rotated(torch.from_numpy(a).float(), torch.from_numpy(b).float()).numpy()
    np.testing.assert_allclose(got32, want, atol=1e-5)
    inter = overlap_bev_rotated(torch.from_numpy(a), torch.from_numpy(b)).numpy()
    np.testing.assert_allclose(inter, [[ref_clip_area(x, y) for y in b] for x in a], atol=1e-10)


def test_iou_axis_aligned_exact():
    rng = np.random.default_rng(13)
    k = 25
    a = np.hstack([rng.integers(-8, 8, (k, 3)) / 4, rng.integers(1, 12, (k, 3)) / 4, np.zeros((k, 1))])
    b = np.hstack([rng.integers(-8, 8, (k, 3)) / 4, rng.integers(1, 12, (k, 3)) / 4, np.zeros((k, 1))])

    def ov(c1, s1, c2, s2):
        return np.clip(np.minimum(c1 + s1 / 2, c2 + s2 / 2) - np.maximum(c1 - s1 / 2, c2 - s2 / 2), 0, None)

    ix = ov(a[:, None, 0], a[:, None, 3], b[None, :, 0], b[None, :, 3])
    iy = ov(a[:, None, 1], a[:, None, 4], b[None, :, 1], b[None, :, 4])
    iz = ov(a[:, None, 2], a[:, None, 5], b[None, :, 2], b[None, :, 5])
    area_a, area_b = a[:, 3] * a[:, 4], b[:, 3] * b[:, 4]
    bev = ix * iy / (area_a[:, None] + area_b[None] - ix * iy)
    vol = ix * iy * iz / (area_a[:, None] * a[:, None, 5] + area_b[None] * b[None, :, 5] - ix * iy * iz)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    np.testing.assert_allclose(iou_bev_rotated(ta, tb).numpy(), bev, rtol=0, atol=1e-14)
    np.testing.assert_allclose(iou3d_rotated(ta, tb).numpy(), vol, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(iou_bev_rotated(ta, tb).numpy() > 0, bev > 0)


def test_iou_identical_disjoint_touching_and_degenerate():
    boxes = torch.tensor([
        [0.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.3],
        [10.0, 0.0, 0.0, 2.0, 1.0, 1.0, -1.0],  # far away
        [2.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.0],  # shares an edge with box 3
        [0.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.0],
        [0.0, 0.0, 5.0, 2.0, 1.0, 1.0, 0.3],  # same footprint as box 0, disjoint in z
        [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0],  # zero footprint
    ], dtype=torch.float64)
    iou = iou_bev_rotated(boxes, boxes)
    assert torch.allclose(iou.diagonal()[:5], torch.ones(5, dtype=torch.float64))
    assert iou[0, 1] == 0 and iou[1, 0] == 0
    assert abs(float(iou[2, 3])) < 1e-12
    assert abs(float(iou[0, 4]) - 1) < 1e-12
    assert (iou[5] == 0).all() and (iou[:, 5] == 0).all()
    iou3 = iou3d_rotated(boxes, boxes)
    assert abs(float(iou3[0, 0]) - 1) < 1e-12 and iou3[0, 4] == 0
    # a box rotated by pi (or a square by pi/2) is the same footprint
    sq = torch.tensor([[1.0, 2.0, 0, 1.5, 1.5, 1, 0.4], [1.0, 2.0, 0, 1.5, 1.5, 1, 0.4 + math.pi / 2]], dtype=torch.float64)
    assert abs(float(iou_bev_rotated(sq[:1], sq[1:])) - 1) < 1e-12
    # box inside another: IoU = small area / big area
    nest = torch.tensor([[0.0, 0, 0, 4, 4, 1, 0.2], [0.1, -0.2, 0, 1, 0.5, 1, 1.1]], dtype=torch.float64)
    assert abs(float(iou_bev_rotated(nest[:1], nest[1:])) - 0.5 / 16) < 1e-12
    assert iou_bev_rotated(boxes[:0], boxes).shape == (0, 6)
    assert bev_corners(boxes).shape == (6, 4, 2)


def ref_nms(boxes, scores, thr):
    order = sorted(range(len(scores)), key=lambda i: (-scores[i], i))
    keep = []
    for i in order:
        if all(ref_iou_bev(boxes[i], boxes[j]) <= thr for j in keep):
            keep.append(i)
    return keep


def test_nms_basic_cases():
    b = torch.tensor([[0.0, 0, 0, 2, 1, 1, 0.1], [0.2, 0.1, 0, 2, 1, 1, 0.0], [5.0, 5, 0, 1, 1, 1, 0.7]])
    keep = nms_bev_rotated(b[:2], torch.tensor([0.3, 0.8]), 0.1)
    assert keep.tolist() == [1]  # overlapping: keep the higher score
    keep = nms_bev_rotated(b[[0, 2]], torch.tensor([0.3, 0.8]), 0.1)
    assert keep.tolist() == [1, 0]  # disjoint: keep both, by descending score
    assert nms_bev_rotated(b, torch.tensor([0.3, 0.8, 0.5]), 0.99).tolist() == [1, 2, 0]
    assert nms_bev_rotated(b, torch.tensor([0.3, 0.8, 0.5]), 0.1, post_max_size=1).tolist() == [1]
    assert nms_bev_rotated(b, torch.tensor([0.3, 0.8, 0.5]), 0.1, pre_max_size=1).tolist() == [1]
    assert nms_bev_rotated(b[:0], torch.zeros(0), 0.1).tolist() == []


def test_nms_matches_reference_greedy_random():
    rng = np.random.default_rng(14)
    boxes = random_boxes(rng, 120, spread=6.0)
    scores = rng.uniform(size=120)
    scores[10] = scores[20]  # a tie: stable order keeps index 10 first
    from sonardet.detect.sasa.ops.rotated_iou import _candidate_pairs

    t = torch.from_numpy(boxes)
    full = _candidate_pairs(t, t, upper=True, row_chunk=10_000)
    chunked = _candidate_pairs(t, t, upper=True, row_chunk=7)
    assert torch.equal(full[0], chunked[0]) and torch.equal(full[1], chunked[1])
    for thr in (0.01, 0.1, 0.5):
        got = nms_bev_rotated(torch.from_numpy(boxes), torch.from_numpy(scores), thr).tolist()
        assert got == ref_nms(boxes, scores, thr)


_TRITON_INTERPRETED_FPS = r"""
import os, sys
os.environ["TRITON_INTERPRET"] = "1"
import torch
from sonardet.detect.sasa.ops import gpu_kernels, sampling
assert gpu_kernels.AVAILABLE
g = torch.Generator().manual_seed(3)
for dtype in (torch.float32, torch.float64):
    for B, N, m, weighted in [(2, 300, 64, False), (2, 300, 300, True), (1, 1, 1, False), (1, 17, 5, True)]:
        xyz = torch.rand(B, N, 3, generator=g, dtype=dtype) * 10 + 300.0
        if N > 30:  # a third of the points on an integer grid (equal distances: ties) with duplicates
            xyz[:, : N // 3] = torch.randint(0, 4, (B, N // 3, 3), generator=g).to(dtype)
            xyz[:, 10:30] = xyz[:, 10:11]
        xp = xyz.index_select(1, sampling._preference_order(N, xyz.device))
        wp = torch.rand(B, N, generator=g, dtype=dtype) if weighted else None
        if weighted:
            wp[:, :4] = 0.0  # below the clamp
        assert torch.equal(sampling._fps_gpu(xp, wp, m), sampling._fps_torch(xp, wp, m)), (dtype, B, N, m, weighted)
print("ok")
"""


def test_triton_fps_kernel_in_the_interpreter():
    """The CUDA FPS kernel (Triton) run by Triton's CPU interpreter picks what the PyTorch loop picks.
    Needs Triton (PyTorch's CUDA builds bring it; skipped with the CPU build). The interpreter breaks
    every argmax tie to the left whatever the kernel asks, so the tie rule and the arithmetic on the
    hardware are tested on a GPU (tests/test_sasa_cuda.py)."""
    import subprocess
    import sys

    pytest.importorskip("triton")
    done = subprocess.run([sys.executable, "-c", _TRITON_INTERPRETED_FPS], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-3000:]
