"""The SASA speed-ups keep the numbers: the batch norm through a 4-D view is bitwise the module's,
the padded grouped MLP is bitwise the textbook one, and the compact grouped MLP (one row per distinct
neighbour, batch norm weighted by multiplicities) agrees with it up to float summation order, in the
forward pass, the gradients and the running statistics."""

from __future__ import annotations

import pytest
import numpy as np
import torch
from torch import nn

from sonardet.detect.sasa import SASADetector, resolve_params
from sonardet.detect.sasa.backbone import GroupedMLP, batch_norm_rows, group_rows
from sonardet.detect.sasa.ops import ball_query_shells, furthest_point_sample, index_points

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _reference_grouped_mlp(m: GroupedMLP, xyz, new_xyz, features, idx, cnt):
    """The grouped MLP written plainly on the padded (B, M, K) slots with the modules' own calls."""
    rel = index_points(xyz, idx) - new_xyz.unsqueeze(2)
    h = m.w_xyz(rel) + index_points(m.w_feat(features), idx)
    shape = h.shape
    h = torch.relu(m.bn0(h.reshape(-1, shape[-1]))).reshape(shape)
    for lin, bn in zip(m.rest.linears, m.rest.norms):
        h = lin(h)
        s = h.shape
        h = torch.relu(bn(h.reshape(-1, s[-1]))).reshape(s)
    h = h * (cnt > 0).to(h.dtype)[:, :, None, None]
    return h.max(dim=2).values


def _groups(seed=0, B=2, N=1500, M=200, K=16):
    g = torch.Generator().manual_seed(seed)
    xyz = torch.rand(B, N, 3, generator=g) * torch.tensor([10.0, 10.0, 1.0])
    feats = torch.randn(B, N, 6, generator=g)
    q = index_points(xyz, furthest_point_sample(xyz, M))
    q[0, :4] += 50.0  # empty balls
    (cnt, idx), = ball_query_shells([0.6], [K], xyz, q)
    return xyz, q, feats, idx, cnt


def _run(m, fn, xyz, q, feats, idx, cnt, grad):
    f = feats.clone().requires_grad_()
    c = q.clone().requires_grad_()
    out = fn(m, xyz, c, f, idx, cnt)
    (out * grad).sum().backward()
    return out.detach(), f.grad, c.grad, [p.grad for p in m.parameters()], [b.clone() for b in m.buffers()]


def _pair(compact: bool):
    torch.manual_seed(3)
    ref = GroupedMLP(6, [16, 32, 24], compact=False)
    m = GroupedMLP(6, [16, 32, 24], compact=compact)
    m.load_state_dict(ref.state_dict())
    return ref, m


def test_batch_norm_rows_is_bitwise_the_module():
    torch.manual_seed(0)
    bn1, bn2 = nn.BatchNorm1d(24), nn.BatchNorm1d(24)
    bn2.load_state_dict(bn1.state_dict())
    x1 = (torch.randn(5000, 24) * 3 + 1).requires_grad_()
    x2 = x1.detach().clone().requires_grad_()
    g = torch.randn(5000, 24)
    for _ in range(2):  # training (batch statistics, running estimates), twice
        (bn1(x1) * g).sum().backward()
        (batch_norm_rows(x2, bn2) * g).sum().backward()
    assert torch.equal(x1.grad, x2.grad) and torch.equal(bn1.weight.grad, bn2.weight.grad)
    assert all(torch.equal(a, b) for a, b in zip(bn1.buffers(), bn2.buffers()))
    bn1.eval()
    bn2.eval()
    assert torch.equal(bn1(x1), batch_norm_rows(x2, bn2))


def test_group_rows_keeps_each_hit_once_with_its_multiplicity():
    xyz, q, feats, idx, cnt = _groups()
    B, M, K = idx.shape
    rows = group_rows(idx, cnt, xyz.shape[1])
    n = cnt.clamp(min=1, max=K).reshape(-1)
    assert torch.equal(rows.lengths, n) and rows.total == B * M * K
    per_centre = torch.zeros(B * M).index_add_(0, rows.centre, rows.weight.float())
    assert torch.all(per_centre == K)  # the multiplicities cover every slot
    flat = (idx + (torch.arange(B) * xyz.shape[1]).view(B, 1, 1)).reshape(B * M, K)
    start = 0
    for c in range(B * M):  # the rows are the distinct slots, in slot order
        k = int(n[c])
        assert torch.equal(rows.point[start:start + k], flat[c, :k])
        assert set(flat[c].tolist()) == set(flat[c, :k].tolist())
        start += k
    assert bool((cnt == 0).any())


def test_padded_grouped_mlp_is_bitwise_the_reference():
    xyz, q, feats, idx, cnt = _groups(1)
    ref, m = _pair(compact=False)
    grad = torch.randn(idx.shape[0], idx.shape[1], 24)
    a = _run(ref, _reference_grouped_mlp, xyz, q, feats, idx, cnt, grad)
    b = _run(m, GroupedMLP.forward, xyz, q, feats, idx, cnt, grad)
    for x, y in zip(a[:3], b[:3]):
        assert torch.equal(x, y)
    assert all(torch.equal(x, y) for x, y in zip(a[3] + a[4], b[3] + b[4]))


def _rel(a, b):
    return float((a - b).abs().max() / b.abs().max().clamp(min=1e-30))


def test_compact_grouped_mlp_agrees_with_padded():
    xyz, q, feats, idx, cnt = _groups(2)
    ref, m = _pair(compact=True)
    grad = torch.randn(idx.shape[0], idx.shape[1], 24)
    a = _run(ref, GroupedMLP.forward, xyz, q, feats, idx, cnt, grad)
    b = _run(m, GroupedMLP.forward, xyz, q, feats, idx, cnt, grad)
    for x, y in zip(list(a[:3]) + a[3] + a[4], list(b[:3]) + b[3] + b[4]):
        assert _rel(y.float(), x.float()) < 1e-4
    assert torch.equal(a[4][2], b[4][2])  # num_batches_tracked
    ref.eval()
    m.eval()
    with torch.no_grad():
        assert _rel(m(xyz, q, feats, idx, cnt), ref(xyz, q, feats, idx, cnt)) < 1e-5


def test_coordinate_linear_is_the_linear_with_its_gradients():
    """The coordinate projection's own backward (transposed products) gives the values and gradients of
    ``F.linear``, for coordinates with and without a gradient (SA layers and the vote SA), and leaves
    inference to ``F.linear`` itself."""
    from sonardet.detect.sasa.backbone import coordinate_linear

    g = torch.Generator().manual_seed(8)
    for R, C, rel_grad in ((5000, 16, False), (700, 128, True)):
        rel = torch.randn(R, 3, generator=g) * 0.5
        weight = torch.randn(C, 3, generator=g)
        up = torch.randn(R, C, generator=g)
        grads = []
        for fn in (torch.nn.functional.linear, coordinate_linear):
            r = rel.clone().requires_grad_(rel_grad)
            w = weight.clone().requires_grad_()
            y = fn(r, w)
            (y * up).sum().backward()
            grads.append((y.detach(), w.grad, r.grad))
        (y1, w1, r1), (y2, w2, r2) = grads
        assert torch.equal(y1, y2)
        assert _rel(w2, w1) < 1e-5
        assert (r1 is None and r2 is None) if not rel_grad else _rel(r2, r1) < 1e-5
        with torch.no_grad():
            assert torch.equal(coordinate_linear(rel, weight), torch.nn.functional.linear(rel, weight))


def test_compact_groups_setting_reaches_every_grouped_mlp():
    tiny = {"n_points": 256, "sa_npoints": [64, 32, 16], "sa_radii_m": [[0.4], [0.8], [1.6]],
            "sa_nsamples": [[8], [8], [8]], "sa_mlps": [[[8]], [[8]], [[8]]], "sa_aggregation": [8, 8, 8],
            "sa_confidence_mlps": [[8], [8]], "vote_mlp": [8], "vote_radii_m": [1.0], "vote_nsamples": [8],
            "vote_mlps": [[8]], "head_shared_fc": [8], "head_cls_fc": [8], "head_reg_fc": [8]}
    for compact in (True, False):
        model = SASADetector(resolve_params({**tiny, "compact_groups": compact}))
        flags = {m.compact for m in model.modules() if isinstance(m, GroupedMLP)}
        assert flags == {compact}


def test_weighted_batch_norm_gradient_is_the_population_gradient():
    # rows standing for 1-3 slots each: the same loss as the plain batch norm of the expanded rows
    from sonardet.detect.sasa.backbone import GroupRows, weighted_batch_norm_relu

    g = torch.Generator().manual_seed(4)
    h = torch.randn(40, 5, generator=g, dtype=torch.float64)
    w = torch.randint(1, 4, (40,), generator=g)
    rows = GroupRows(torch.arange(40), torch.arange(40), w, torch.ones(40, dtype=torch.long), int(w.sum()))
    up = torch.randn(40, 5, generator=g, dtype=torch.float64)
    bn1, bn2 = nn.BatchNorm1d(5).double(), nn.BatchNorm1d(5).double()
    with torch.no_grad():
        bn1.weight.uniform_(0.5, 1.5)
        bn1.bias.uniform_(-0.5, 0.5)
    bn2.load_state_dict(bn1.state_dict())
    h1, h2 = h.clone().requires_grad_(), h.clone().requires_grad_()
    y1 = weighted_batch_norm_relu(h1, bn1, rows)
    # the padded population: row i repeated w_i times, its gradient arriving on the first copy
    rep = torch.repeat_interleave(torch.arange(40), w)
    first = torch.ones_like(rep, dtype=torch.bool)
    first[1:] = rep[1:] != rep[:-1]
    y2 = torch.relu(bn2(h2[rep]))
    (y1 * up).sum().backward()
    (y2 * (up[rep] * first[:, None])).sum().backward()
    assert torch.allclose(y1, y2[first], atol=1e-12)
    assert torch.allclose(h1.grad, h2.grad, atol=1e-10)
    assert torch.allclose(bn1.weight.grad, bn2.weight.grad, atol=1e-10)
    assert torch.allclose(bn1.bias.grad, bn2.bias.grad, atol=1e-10)
    assert all(torch.allclose(a.double(), b.double(), atol=1e-12) for a, b in zip(bn1.buffers(), bn2.buffers()))


def test_fused_weighted_batch_norm_kernel_equals_torch_formulation(monkeypatch):
    from sonardet.detect.sasa import backbone
    from sonardet.detect.sasa.backbone import GroupRows, weighted_batch_norm_relu

    assert backbone.kernels is not None
    g = torch.Generator().manual_seed(6)
    h = torch.randn(3000, 24, generator=g) * 2 + 5  # an offset mean: the statistics must not cancel
    w = torch.randint(1, 5, (3000,), generator=g)
    rows = GroupRows(torch.arange(3000), torch.arange(3000), w, torch.ones(3000, dtype=torch.long), int(w.sum()))
    up = torch.randn(3000, 24, generator=g)
    out = []
    for fused in (True, False):
        if not fused:
            monkeypatch.setattr(backbone, "kernels", None)
        torch.manual_seed(1)
        bn = nn.BatchNorm1d(24)
        with torch.no_grad():
            bn.weight.uniform_(0.5, 1.5)
            bn.bias.uniform_(-0.5, 0.5)
        x = h.clone().requires_grad_()
        y = weighted_batch_norm_relu(x, bn, rows)
        (y * up).sum().backward()
        out.append([y.detach(), x.grad, bn.weight.grad, bn.bias.grad, bn.running_mean, bn.running_var])
    for a, b in zip(*out):
        assert _rel(a, b) < 1e-5


def test_fused_weighted_batch_norm_statistics_survive_a_large_offset():
    """The kernel's weighted mean and variance (accumulated around a provisional mean from a row
    sample) equal float64 NumPy's on rows with a mean 1e6 times their spread, uneven weights and a
    row count that is no multiple of the sample stride."""
    from sonardet.detect.sasa.ops import kernels

    rng = np.random.default_rng(7)
    R, C = 50_003, 16
    h = (1e4 + 1e-2 * rng.standard_normal((R, C))).astype(np.float32)
    w = rng.integers(1, 9, R).astype(np.float64)
    wn = (w / w.sum()).astype(np.float32)
    gamma = np.ones(C, dtype=np.float32)
    beta = np.zeros(C, dtype=np.float32)
    y, mean, var = kernels.weighted_bn_relu_forward(h, wn, gamma, beta, 1e-5, 2)
    hd, wd = h.astype(np.float64), wn.astype(np.float64)
    wd = wd / wd.sum()  # the float32 weights sum to 1 up to rounding; the kernel divides by their sum
    want_mean = wd @ hd
    want_var = wd @ (hd - want_mean) ** 2
    np.testing.assert_allclose(mean, want_mean, rtol=1e-13)
    np.testing.assert_allclose(var, want_var, rtol=1e-6)
    assert 0.5e-4 < float(np.sqrt(want_var.mean())) < 2e-2  # the spread survived (float32 steps of 1e4: 1e-3)
    assert np.isfinite(y).all() and (y >= 0).all()


def test_fused_segment_max_is_bitwise_torch_segment_reduce():
    """Values and gradients of the grouped MLP's pooling equal torch.segment_reduce's to the bit, with
    ties (ReLU zeros, repeated values), one-row segments, NaN and gradients of both signs."""
    from sonardet.detect.sasa import backbone
    from sonardet.detect.sasa.backbone import _FusedSegmentMax, segment_max

    assert backbone.kernels is not None
    g = torch.Generator().manual_seed(11)
    lengths = torch.randint(1, 9, (700,), generator=g)
    lengths[:50] = 1
    lengths[50] = 3  # rows 50-52: the all -inf segment below
    R = int(lengths.sum())
    h = torch.relu(torch.round(torch.randn(R, 16, generator=g) * 2) / 2)  # many ties, at 0 and above
    h[5, 3] = float("nan")
    h[50:53, 1] = -float("inf")  # a segment whose channel is all -inf; signed zeros below
    h[60, 2], h[61, 2] = -0.0, 0.0
    up = torch.randn(len(lengths), 16, generator=g)
    grads = []
    for fn in (lambda x: torch.segment_reduce(x, "max", lengths=lengths, axis=0, unsafe=True),
               lambda x: _FusedSegmentMax.apply(x, lengths), lambda x: segment_max(x, lengths)):
        x = h.clone().requires_grad_()
        y = fn(x)
        (y * up).sum().backward()
        grads.append((y.detach(), x.grad))
    (y_ref, g_ref) = grads[0]
    assert (g_ref != 0).sum() > lengths.numel() * 16  # ties: some channel's max is on two or more rows
    for y, gi in grads[1:]:
        assert torch.equal(torch.nan_to_num(y, nan=-7.0), torch.nan_to_num(y_ref, nan=-7.0))
        assert torch.equal(torch.signbit(y), torch.signbit(y_ref))
        assert torch.equal(gi, g_ref)


def test_fused_kernels_give_the_same_bits_on_one_thread_and_in_parallel():
    """The batch-norm and segment-max kernels run their row chunks in parallel only on large arrays
    (``kernels.run_parallel``); both paths must give the same numbers, bit for bit, since the chunks
    fix the order of every sum. And the ReLU mask the backward recomputes from h is the forward's."""
    from sonardet.detect.sasa.ops import kernels

    rng = np.random.default_rng(3)
    R, C, nchunks = 20_011, 24, 8
    h = (rng.standard_normal((R, C)) * 2 + 0.5).astype(np.float32)
    wn = rng.integers(1, 6, R).astype(np.float32)
    wn /= wn.sum()
    gamma = rng.uniform(-1.5, 1.5, C).astype(np.float32)
    beta = rng.uniform(-0.5, 0.5, C).astype(np.float32)
    gy = rng.standard_normal((R, C)).astype(np.float32)
    offsets = np.concatenate([[0], np.cumsum(rng.integers(1, 9, 3000))])
    offsets = offsets[offsets < R]
    offsets[-1] = R
    out = {}
    for parallel in (True, False):
        y, mean, var = kernels.weighted_bn_relu_forward(h, wn, gamma, beta, 1e-5, nchunks, parallel)
        invstd = 1.0 / np.sqrt(var + 1e-5)
        dh, dgamma, dbeta = kernels.weighted_bn_relu_backward(gy, h, wn, mean, var, invstd, gamma, beta, 1e-5,
                                                              nchunks, parallel)
        m = kernels.segment_max_forward(y, offsets, nchunks, parallel)
        gm = kernels.segment_max_backward(gy[:len(offsets) - 1], m, y, offsets, nchunks, parallel)
        out[parallel] = (y, mean, var, dh, dgamma, dbeta, m, gm)
    for a, b in zip(out[True], out[False]):
        assert a.tobytes() == b.tobytes()
    # the backward's recomputed ReLU mask is the forward's (y > 0): against a float64 reference
    y, mean, var, dh, dgamma, dbeta = out[True][:6]
    invstd = 1.0 / np.sqrt(var + 1e-5)
    g = np.where(y > 0, gy, 0).astype(np.float64)
    xhat = (h.astype(np.float64) - mean) * invstd
    sb, sg = g.sum(axis=0), (g * xhat).sum(axis=0)
    want = gamma * invstd * (g - wn[:, None] * (sb + xhat * sg))
    assert 0 < (y == 0).mean() < 1
    np.testing.assert_allclose(dbeta, sb, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(dgamma, sg, rtol=1e-5)  # xhat in float32, as the forward
    np.testing.assert_allclose(dh, want, rtol=1e-4, atol=1e-6 * np.abs(want).max())
    assert not kernels.run_parallel(kernels.PARALLEL_MIN_ELEMENTS - 1)


def test_fused_batch_norm_backward_is_its_row_order_formulation_bit_for_bit():
    """The backward kernel computes exactly this: per chunk of rows, float64 sums of the masked
    gradient and of its product with the float32 xhat, row after row; then dh in float32 operations.
    Row by row in NumPy (each step elementwise, so the same IEEE operations in the same order) the
    result must be the same bits, signs of zeros included: a rewrite of the kernel for speed (e.g. its
    reads of gy taken out of the mask's condition) may not change a training."""
    from sonardet.detect.sasa.ops import kernels

    rng = np.random.default_rng(11)
    R, C, nchunks = 1_003, 13, 4
    h = (rng.standard_normal((R, C)) * 2 + 0.5).astype(np.float32)
    gy = rng.standard_normal((R, C)).astype(np.float32)
    gy[rng.random((R, C)) < 0.05] = -0.0
    gy[:, 3] = 0.0  # a channel whose sums are zeros
    wn = rng.integers(1, 6, R).astype(np.float32)
    wn /= wn.sum()
    gamma = rng.uniform(-1.5, 1.5, C).astype(np.float32)
    beta = rng.uniform(-0.5, 0.5, C).astype(np.float32)
    _, mean, var = kernels.weighted_bn_relu_forward(h, wn, gamma, beta, 1e-5, nchunks, False)
    invstd = 1.0 / np.sqrt(var + 1e-5)
    dh, dgamma, dbeta = kernels.weighted_bn_relu_backward(gy, h, wn, mean, var, invstd, gamma, beta, 1e-5,
                                                          nchunks, False)
    scale, offset = kernels._bn_affine(mean, var, gamma, beta, 1e-5)
    mean32, inv32 = mean.astype(np.float32), invstd.astype(np.float32)
    sb, sg = np.zeros((nchunks, C)), np.zeros((nchunks, C))
    for k in range(nchunks):
        for i in range(k * R // nchunks, (k + 1) * R // nchunks):
            g = np.where(h[i] * scale + offset > 0, gy[i].astype(np.float64), 0.0)
            sb[k] += g
            sg[k] += g * ((h[i] - mean32) * inv32).astype(np.float64)
    want_db, want_dg = sb.sum(axis=0), sg.sum(axis=0)
    a = (gamma.astype(np.float64) * invstd).astype(np.float32)
    db32, dg32 = want_db.astype(np.float32), want_dg.astype(np.float32)
    want_dh = np.empty_like(h)
    for i in range(R):
        g = np.where(h[i] * scale + offset > 0, gy[i], np.float32(0.0))
        xhat = (h[i] - mean32) * inv32
        want_dh[i] = a * (g - wn[i] * (db32 + xhat * dg32))
    assert dbeta.tobytes() == want_db.tobytes() and dgamma.tobytes() == want_dg.tobytes()
    assert dh.tobytes() == want_dh.tobytes()


def test_fused_last_layer_and_max_kernels_are_the_two_steps_bit_for_bit():
    """`bn_relu_segment_max_forward` / ``_backward`` give the same max, statistics and gradients, bit for
    bit, as the batch-norm + ReLU kernels followed by the segment-max kernels on the calling thread:
    with ties above zero (quantised inputs), one-row segments, chunk boundaries inside segments,
    gradients of both signs and signed zeros."""
    from sonardet.detect.sasa.ops import kernels

    rng = np.random.default_rng(5)
    lengths = rng.integers(1, 12, 1500)
    lengths[:40] = 1
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    R, C, nchunks = int(offsets[-1]), 19, 7
    h = (np.round(rng.standard_normal((R, C)) * 4) / 4 + 0.3).astype(np.float32)  # many equal values
    wn = rng.integers(1, 6, R).astype(np.float32)
    wn /= wn.sum()
    gamma = rng.uniform(-1.5, 1.5, C).astype(np.float32)
    beta = rng.uniform(-0.5, 0.5, C).astype(np.float32)
    g = rng.standard_normal((len(lengths), C)).astype(np.float32)
    g[rng.random(g.shape) < 0.05] = -0.0
    y, mean, var = kernels.weighted_bn_relu_forward(h, wn, gamma, beta, 1e-5, nchunks, False)
    m = kernels.segment_max_forward(y, offsets, nchunks, False)
    invstd = 1.0 / np.sqrt(var + 1e-5)
    gy = kernels.segment_max_backward(g, m, y, offsets, nchunks, False)
    dh, dgamma, dbeta = kernels.weighted_bn_relu_backward(gy, h, wn, mean, var, invstd, gamma, beta, 1e-5, nchunks,
                                                          False)
    m2, ties, mean2, var2 = kernels.bn_relu_segment_max_forward(h, wn, gamma, beta, 1e-5, offsets, nchunks)
    dh2, dgamma2, dbeta2 = kernels.bn_relu_segment_max_backward(g, m2, ties, h, wn, mean2, var2, invstd, gamma, beta,
                                                                1e-5, offsets, nchunks)
    # the case the ties exist for: two or more rows of a segment at the same positive max
    seg = np.repeat(np.arange(len(lengths)), lengths)
    assert ((ties >= 2) & (m2 > 0)).sum() > 100
    assert np.array_equal(ties, np.add.reduceat((y == m[seg]).astype(np.int32), offsets[:-1], axis=0))
    for a, b in ((m, m2), (mean, mean2), (var, var2), (dh, dh2), (dgamma, dgamma2), (dbeta, dbeta2)):
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes()


def test_grouped_mlp_with_the_fused_last_layer_is_bitwise_the_unfused(monkeypatch):
    """A compact grouped MLP trains to the same bits with its last batch norm + ReLU and the max over
    the groups fused (`weighted_batch_norm_relu_max`) and run one after the other: outputs, every
    gradient and the running statistics, over two training steps, and in evaluation."""
    from sonardet.detect.sasa import backbone

    xyz, q, feats, idx, cnt = _groups(seed=4)
    calls = []
    fused = backbone._FusedWeightedBatchNormReLUMax.apply
    monkeypatch.setattr(backbone._FusedWeightedBatchNormReLUMax, "apply",
                        lambda *a: calls.append(1) or fused(*a))
    outs = {}
    for fuse in (False, True):
        monkeypatch.setattr(backbone, "FUSE_LAST_MAX", fuse)
        torch.manual_seed(3)
        m = GroupedMLP(6, [16, 32, 24], compact=True)
        g = torch.Generator().manual_seed(8)
        runs = []
        for _ in range(2):
            m.zero_grad()
            runs.append(_run(m, lambda mod, *a: mod(*a), xyz, q, feats, idx, cnt,
                             torch.randn(q.shape[0], q.shape[1], 24, generator=g)))
        m.eval()
        with torch.no_grad():
            runs.append(m(xyz, q, feats, idx, cnt))
        outs[fuse] = runs
    assert int((cnt == 0).sum()) > 0
    assert len(calls) == 2  # the fused function ran in both training steps (and only with FUSE_LAST_MAX)

    def flat(x):
        if isinstance(x, (list, tuple)):
            return [t for y in x for t in flat(y)]
        return [x]

    a, b = flat(outs[False]), flat(outs[True])
    assert len(a) == len(b) > 10
    for x, y in zip(a, b):
        assert x.dtype == y.dtype and torch.equal(x, y)


def test_one_layer_grouped_mlp_fuses_its_only_layer(monkeypatch):
    """With a single layer the fused function takes the first batch norm (bn0); same bits as unfused."""
    from sonardet.detect.sasa import backbone

    xyz, q, feats, idx, cnt = _groups(seed=6)
    res = []
    for fuse in (False, True):
        monkeypatch.setattr(backbone, "FUSE_LAST_MAX", fuse)
        torch.manual_seed(2)
        m = GroupedMLP(6, [12], compact=True)
        res.append(_run(m, lambda mod, *a: mod(*a), xyz, q, feats, idx, cnt, torch.ones(q.shape[0], q.shape[1], 12)))
    for x, y in zip(res[0][:3], res[1][:3]):
        assert torch.equal(x, y)
    assert all(torch.equal(x, y) for x, y in zip(res[0][3], res[1][3]))


@pytest.mark.parametrize("widths", [[16, 24], [12]])  # [12], fused: the only batch norm is the fused last layer's
@pytest.mark.parametrize("fuse", [False, True])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_a_non_finite_activation_is_an_error_not_zeros(monkeypatch, fuse, bad, widths):
    """The fused batch-norm kernels would turn a channel with a NaN or infinite row into ReLU zeros
    (PyTorch's formulation gives NaN, which the trainer's non-finite-loss check catches): both fused
    paths raise FloatingPointError instead, naming the cause; PyTorch's path (float64 rows) still
    gives NaN."""
    from sonardet.detect.sasa import backbone

    monkeypatch.setattr(backbone, "FUSE_LAST_MAX", fuse)
    xyz, q, feats, idx, cnt = _groups(seed=5)
    feats[1, int(idx[1, 7, 0]), 2] = bad  # a neighbour of a non-empty group
    torch.manual_seed(1)
    m = GroupedMLP(6, widths, compact=True)
    with pytest.raises(FloatingPointError, match="non-finite activations entering a SASA batch norm"):
        m(xyz, q, feats, idx, cnt)
    m64 = GroupedMLP(6, widths, compact=True).double()
    out = m64(xyz.double(), q.double(), feats.double(), idx, cnt)
    assert torch.isnan(out).any()
