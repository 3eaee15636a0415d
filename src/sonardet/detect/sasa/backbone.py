"""PointNet++ backbone with SASA sampling (reference ``PointNet2FSMSG`` + ``PointnetSAModuleFSMSG``).

Three set-abstraction layers (see config.py for the sonar hyper-parameters):

* SA1: D-FPS over all input points;
* SA2: S-FPS (driven by the SA1 segmentation logits) + D-FPS, both over all SA1 points;
* SA3: S-FPS over the S-FPS half of SA2 (SA2 logits) + D-FPS over the D-FPS half.

Each layer: sample centres -> multi-scale (dilated shell) ball query -> [relative xyz (m), features]
-> shared MLP (linear, no bias, BN, ReLU) -> zero empty groups -> max-pool -> concat -> aggregation
(linear, BN, ReLU) -> optional segmentation branch (linear/BN/ReLU ... -> 1 logit). Sampling and ball
queries use :mod:`sonardet.detect.sasa.ops` (no gradients through indices).

CPU-oriented implementation (same function as the reference's 1x1 convolutions):

* features are channel-last, (B, N, C), and the shared MLPs are ``nn.Linear`` layers on the last
  dimension (a GEMM; ~1.5-2x faster than a 1x1 ``Conv2d`` on CPU);
* the first layer of a grouped MLP is linear in ``[x_j - c, f_j]``, so ``W [x_j - c; f_j] =
  W_xyz (x_j - c) + (W_f f)_j``: ``W_f f`` is computed once per input point and gathered, instead of
  once per (centre, neighbour) pair -- exact, and it removes most of the cost of SA3 and the vote SA;
* a ball query pads a centre with fewer than K hits by repeating them, so most slots are copies
  (about a quarter in ``DEFAULTS``, five sixths in ``STUDY``): the grouped MLPs run once per distinct
  (centre, neighbour) pair with a batch norm weighted by the multiplicities and a segment max
  (:class:`GroupedMLP`, ``compact_groups``; equal up to float summation order; ``False`` keeps the
  padded computation, bit for bit as before);
* batch norms run through a 4-D view (:func:`batch_norm_rows`; bitwise the module's output, about
  twice as fast on CPU).
"""

from __future__ import annotations

from contextlib import contextmanager
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .ops import ball_query_shells, furthest_point_sample, index_points, semantic_furthest_point_sample

try:  # fused CPU kernels of the weighted batch norm (optional: the PyTorch formulation runs without Numba)
    from .ops import kernels
except ImportError:  # pragma: no cover - Numba is a dependency
    kernels = None

__all__ = ["MLP", "GroupedMLP", "GroupRows", "SALayer", "SASABackbone", "batch_norm_rows", "coordinate_linear",
           "group_rows", "limit_threads", "shared_mlp1d", "weighted_batch_norm_relu"]


@contextmanager
def limit_threads(n: int | None):
    """Run the enclosed torch CPU ops with at most ``n`` intra-op threads (None/0: unchanged).

    FPS and ball query issue thousands of small ops; on CPU their threading overhead dominates (a
    2048-step D-FPS on 4 x 8192 points: 0.25 s on 1 thread, 3-4 s on 2 threads of a busy 2-core
    machine), while the convolutions gain from every thread. Sampling therefore runs single-threaded
    in PyTorch (the compiled kernels of :mod:`.ops.kernels` run one thread per cloud of the batch instead).
    """
    old = torch.get_num_threads()
    if not n or n >= old:
        yield
        return
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def batch_norm_rows(x: torch.Tensor, bn: nn.BatchNorm1d) -> torch.Tensor:
    """``bn`` applied to rows x (R, C), through a (R, C, 1, 1) view: a new tensor, which the callers
    rectify in place (``relu_``: the batch norm's backward reads its input, not its output).

    The same numbers as ``bn(x)`` (checked bit for bit in the tests), in about half the time on
    CPU: PyTorch's 2-D kernel strides over the channels point by point, the 4-D one vectorises them.
    """
    R, C = x.shape
    factor = 0.0 if bn.momentum is None else bn.momentum  # as nn.BatchNorm1d.forward
    if bn.training and bn.track_running_stats:
        bn.num_batches_tracked.add_(1)
        if bn.momentum is None:
            factor = 1.0 / float(bn.num_batches_tracked)
    stats = bn.training or (bn.running_mean is None and bn.running_var is None)
    keep = not bn.training or bn.track_running_stats
    y = F.batch_norm(x.view(R, C, 1, 1), bn.running_mean if keep else None, bn.running_var if keep else None,
                     bn.weight, bn.bias, stats, factor, bn.eps)
    return y.view(R, C)


class MLP(nn.Module):
    """Channel-last shared MLP: (Linear no bias -> BatchNorm1d -> ReLU) per width on the last dim."""

    def __init__(self, in_ch: int, widths):
        super().__init__()
        self.linears = nn.ModuleList()
        self.norms = nn.ModuleList()
        c = in_ch
        for w in widths:
            self.linears.append(nn.Linear(c, w, bias=False))
            self.norms.append(nn.BatchNorm1d(w))
            c = w
        self.out_ch = c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(..., in_ch) -> (..., widths[-1])."""
        shape = x.shape[:-1]
        for lin, bn in zip(self.linears, self.norms):
            x = batch_norm_rows(lin(x).reshape(-1, lin.out_features), bn).relu_().reshape(*shape, lin.out_features)
        return x


def shared_mlp1d(in_ch: int, widths) -> tuple[MLP, int]:
    """Channel-last MLP of ``widths`` (may be empty: identity); returns (module, out channels)."""
    m = MLP(in_ch, widths)
    return m, m.out_ch


class GroupRows(NamedTuple):
    """The distinct (centre, neighbour) pairs of a ball query, one row each, grouped by centre.

    A ball query pads a centre's ``cnt < K`` hits by repeating them cyclically (slot j holds hit
    ``j mod cnt``; an empty ball holds K times point 0), so a grouped MLP sees each hit several times
    with identical inputs and outputs. The rows keep each distinct pair once with its multiplicity:

    * ``point`` (R,) int64: neighbour index into the flattened (B * N) points;
    * ``centre`` (R,) int64: centre index into the flattened (B * M) centres (non-decreasing);
    * ``weight`` (R,) float: how many of the K slots hold this pair (``K // n + (j < K % n)`` for
      the j-th of n distinct hits);
    * ``lengths`` (B * M,) int64: rows per centre, ``max(min(cnt, K), 1)``;
    * ``total``: B * M * K, the number of slots (the batch-norm population).
    """

    point: torch.Tensor
    centre: torch.Tensor
    weight: torch.Tensor
    lengths: torch.Tensor
    total: int


def group_rows(idx: torch.Tensor, cnt: torch.Tensor, n_points: int) -> GroupRows:
    """:class:`GroupRows` of a ball query's ``idx`` (B, M, K) and ``cnt`` (B, M) over ``n_points`` points."""
    B, M, K = idx.shape
    n = cnt.clamp(min=1, max=K)  # distinct rows per centre (an empty ball keeps one row: point 0)
    slot = torch.arange(K, device=idx.device)
    keep = slot < n.unsqueeze(-1)  # (B, M, K)
    mult = torch.div(K, n, rounding_mode="floor").unsqueeze(-1) + (slot < (K % n).unsqueeze(-1)).long()
    base = (torch.arange(B, device=idx.device) * n_points).view(B, 1, 1)
    lengths = n.reshape(-1)
    centre = torch.repeat_interleave(torch.arange(B * M, device=idx.device), lengths)
    sel = keep.reshape(-1).nonzero().squeeze(1)  # the kept slots in row-major order, found once
    point = (idx + base).reshape(-1).index_select(0, sel)
    return GroupRows(point, centre, mult.reshape(-1).index_select(0, sel), lengths, B * M * K)


class _WeightedBatchNormReLU(torch.autograd.Function):
    """ReLU(batch norm) of rows h (R, C) with row weights ``wn`` (R,) summing to 1 (multiplicity /
    population): forward returns (y, mean, biased var); backward is the batch-norm gradient of the
    population the rows stand for, ``dh_i = gamma invstd (G_i - wn_i (sum G + xhat_i sum G xhat))``
    with ``G`` the gradient after the ReLU (a few passes over (R, C) instead of autograd's dozen)."""

    @staticmethod
    def forward(ctx, h, wn, gamma, beta, eps):
        mean = wn @ h
        xhat = h - mean
        var = wn @ (xhat * xhat)
        invstd = torch.rsqrt(var + eps)
        xhat.mul_(invstd)
        y = torch.addcmul(beta, xhat, gamma).relu_()
        ctx.save_for_backward(xhat, y, wn, gamma, invstd)
        ctx.mark_non_differentiable(mean, var)
        return y, mean, var

    @staticmethod
    def backward(ctx, gy, _gmean, _gvar):
        xhat, y, wn, gamma, invstd = ctx.saved_tensors
        g = torch.ops.aten.threshold_backward(gy, y, 0)  # gradient before the ReLU
        dbeta = g.sum(0)
        dgamma = (g * xhat).sum(0)
        corr = torch.addcmul(dbeta, xhat, dgamma).mul_(wn.unsqueeze(1))
        dh = g.sub_(corr).mul_(gamma * invstd)
        return dh, None, dgamma, dbeta, None


def _kernel_chunks(h: torch.Tensor) -> tuple[int, bool]:
    """The row chunks (for torch's thread count) and whether to run them in parallel, for a fused
    kernel over h: the last two arguments of every kernel of :mod:`.ops.kernels` called here."""
    return kernels.parallel_chunks(torch.get_num_threads()), kernels.run_parallel(h.numel())


def _check_finite_stats(mean: np.ndarray, var: np.ndarray, h: torch.Tensor) -> None:
    """Raise FloatingPointError when a batch-norm statistic computed by the fused kernels is not finite.

    The kernels assume finite rows: a NaN or infinite activation makes its channel's mean non-finite
    (the float64 sums of finite float32 rows cannot overflow) and the kernels' ReLU would then write
    zeros where PyTorch writes NaN, hiding a diverged training from the trainer's non-finite-loss
    check. This is that check, earlier: the same error type, before anything is written."""
    ok = np.isfinite(mean) & np.isfinite(var)
    if not ok.all():
        bad = int((~ok).sum())
        raise FloatingPointError(
            f"non-finite activations entering a SASA batch norm ({bad} of {len(mean)} channels, rows "
            f"{tuple(h.shape)}): the training diverged or its input holds NaN/inf; lower the learning rate "
            "(`lr`) or check the scenes")


class _FusedWeightedBatchNormReLU(torch.autograd.Function):
    """:class:`_WeightedBatchNormReLU` through the fused CPU kernels of :mod:`.ops.kernels` (float32)."""

    @staticmethod
    def forward(ctx, h, wn, gamma, beta, eps):
        y, mean, var = kernels.weighted_bn_relu_forward(h.detach().numpy(), wn.numpy(), gamma.detach().numpy(),
                                                        beta.detach().numpy(), float(eps), *_kernel_chunks(h))
        _check_finite_stats(mean, var, h)
        y, mean, var = torch.from_numpy(y), torch.from_numpy(mean), torch.from_numpy(var)
        ctx.save_for_backward(h, wn, gamma, beta, mean, var, torch.rsqrt(var + eps))
        ctx.eps = float(eps)
        mean, var = mean.to(h.dtype), var.to(h.dtype)
        ctx.mark_non_differentiable(mean, var)
        return y, mean, var

    @staticmethod
    def backward(ctx, gy, _gmean, _gvar):
        h, wn, gamma, beta, mean, var, invstd = ctx.saved_tensors
        dh, dgamma, dbeta = kernels.weighted_bn_relu_backward(gy.contiguous().numpy(), h.detach().numpy(), wn.numpy(),
                                                              mean.numpy(), var.numpy(), invstd.numpy(),
                                                              gamma.detach().numpy(), beta.detach().numpy(), ctx.eps,
                                                              *_kernel_chunks(h))
        return torch.from_numpy(dh), None, torch.from_numpy(dgamma).to(h.dtype), torch.from_numpy(dbeta).to(h.dtype), None


def _fused_ok(h: torch.Tensor) -> bool:
    return kernels is not None and h.device.type == "cpu" and h.dtype == torch.float32 and h.is_contiguous()


def _segments_fusable(h: torch.Tensor, lengths: torch.Tensor) -> bool:
    """Whether the segment max of h (R, C) over ``lengths`` (S,) can run through the fused kernels:
    CPU float32 rows and at least one segment, every one non-empty."""
    return _fused_ok(h) and lengths.device.type == "cpu" and len(lengths) > 0 and bool((lengths > 0).all())


def _segment_offsets(lengths: torch.Tensor) -> torch.Tensor:
    """First row (S + 1,) int64 of each contiguous segment of ``lengths`` (S,) rows, and the total."""
    offsets = torch.zeros(len(lengths) + 1, dtype=torch.int64)
    torch.cumsum(lengths.to(torch.int64), 0, out=offsets[1:])
    return offsets


class _FusedSegmentMax(torch.autograd.Function):
    """``torch.segment_reduce(h, "max", lengths)`` over contiguous row segments (all non-empty) through
    the CPU kernels of :mod:`.ops.kernels` (float32): the same values and the same gradient, bit for bit
    (``tests/test_sasa_speed.py``)."""

    @staticmethod
    def forward(ctx, h, lengths):
        offsets = _segment_offsets(lengths)
        out = torch.from_numpy(kernels.segment_max_forward(h.detach().numpy(), offsets.numpy(), *_kernel_chunks(h)))
        ctx.save_for_backward(h, out, offsets)
        return out

    @staticmethod
    def backward(ctx, g):
        h, out, offsets = ctx.saved_tensors
        gi = kernels.segment_max_backward(g.contiguous().numpy(), out.numpy(), h.detach().numpy(), offsets.numpy(),
                                          *_kernel_chunks(h))
        return torch.from_numpy(gi), None


def segment_max(h: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Max (S, C) over the contiguous row segments of h (R, C) with ``lengths`` (S,) rows each (every
    length at least 1): ``torch.segment_reduce(h, "max", ...)``, through the fused kernels on CPU float32
    (PyTorch's CPU backward of it walks each channel separately and cost more than the forward)."""
    if _segments_fusable(h, lengths):
        return _FusedSegmentMax.apply(h, lengths)
    return torch.segment_reduce(h, "max", lengths=lengths, axis=0, unsafe=True)


class _FusedWeightedBatchNormReLUMax(torch.autograd.Function):
    """:class:`_FusedWeightedBatchNormReLU` followed by :class:`_FusedSegmentMax` in one function (CPU
    float32, on the calling thread): the same max, statistics and gradients, bit for bit, without the
    (R, C) output and gradient between the two (``kernels.bn_relu_segment_max_forward``); every
    segment non-empty. Forward returns (max (S, C), mean, var)."""

    @staticmethod
    def forward(ctx, h, wn, gamma, beta, eps, offsets, nchunks):
        out, ties, mean, var = kernels.bn_relu_segment_max_forward(
            h.detach().numpy(), wn.numpy(), gamma.detach().numpy(), beta.detach().numpy(), float(eps),
            offsets.numpy(), nchunks)
        _check_finite_stats(mean, var, h)
        out, ties, mean, var = (torch.from_numpy(x) for x in (out, ties, mean, var))
        ctx.save_for_backward(h, wn, gamma, beta, mean, var, torch.rsqrt(var + eps), out, ties, offsets)
        ctx.eps, ctx.nchunks = float(eps), nchunks
        mean, var = mean.to(h.dtype), var.to(h.dtype)
        ctx.mark_non_differentiable(mean, var)
        return out, mean, var

    @staticmethod
    def backward(ctx, g, _gmean, _gvar):
        h, wn, gamma, beta, mean, var, invstd, out, ties, offsets = ctx.saved_tensors
        dh, dgamma, dbeta = kernels.bn_relu_segment_max_backward(
            g.contiguous().numpy(), out.numpy(), ties.numpy(), h.detach().numpy(), wn.numpy(), mean.numpy(),
            var.numpy(), invstd.numpy(), gamma.detach().numpy(), beta.detach().numpy(), ctx.eps, offsets.numpy(),
            ctx.nchunks)
        return (torch.from_numpy(dh), None, torch.from_numpy(dgamma).to(h.dtype), torch.from_numpy(dbeta).to(h.dtype),
                None, None, None)


def _update_running_stats(bn: nn.BatchNorm1d, mean: torch.Tensor, var: torch.Tensor, rows: GroupRows) -> None:
    """The batch norm's running mean and (unbiased) variance after a training batch of ``rows.total``
    slots with batch statistics mean, biased var."""
    with torch.no_grad():
        bn.num_batches_tracked.add_(1)
        f = 1.0 / float(bn.num_batches_tracked) if bn.momentum is None else bn.momentum
        n = rows.total
        bn.running_mean.mul_(1.0 - f).add_(mean, alpha=f)
        bn.running_var.mul_(1.0 - f).add_(var, alpha=f * n / max(n - 1, 1))


def _check_weighted_bn(bn: nn.BatchNorm1d) -> None:
    if not (bn.track_running_stats and bn.affine):
        raise ValueError("the weighted batch norm needs an affine batch norm with running statistics")


#: Whether the last batch norm + ReLU of a compact grouped MLP and the max over its groups run as one
#: function on CPU (`weighted_batch_norm_relu_max`); False runs them one after the other (the same
#: numbers; the tests compare the two).
FUSE_LAST_MAX = True


def weighted_batch_norm_relu_max(h: torch.Tensor, bn: nn.BatchNorm1d, rows: GroupRows) -> torch.Tensor:
    """``segment_max(weighted_batch_norm_relu(h, bn, rows), rows.lengths)``: the max (S, C) over each
    group's rows of ReLU(BatchNorm(h)), in one fused function where it applies (training, CPU float32,
    every group non-empty, the kernels on the calling thread), the two steps otherwise; the same
    numbers, gradients and running statistics either way."""
    lengths = rows.lengths
    if FUSE_LAST_MAX and bn.training and _segments_fusable(h, lengths):
        nchunks, parallel = _kernel_chunks(h)
        if not parallel:
            _check_weighted_bn(bn)
            wn = rows.weight.to(h.dtype) / rows.total
            out, mean, var = _FusedWeightedBatchNormReLUMax.apply(h, wn, bn.weight, bn.bias, bn.eps,
                                                                  _segment_offsets(lengths), nchunks)
            _update_running_stats(bn, mean, var, rows)
            return out
    return segment_max(weighted_batch_norm_relu(h, bn, rows), lengths)


def weighted_batch_norm_relu(h: torch.Tensor, bn: nn.BatchNorm1d, rows: GroupRows) -> torch.Tensor:
    """ReLU(BatchNorm(h)) of rows h (R, C) that stand for ``rows.weight`` slots each.

    Training: the batch statistics (mean, biased variance; unbiased variance for the running
    estimate) are those of the ``rows.total`` slots, i.e. weighted by the multiplicities: the same
    numbers as the batch norm of the padded (B * M * K, C) tensor up to float summation order, and
    so are the gradients. Evaluation: the running statistics, row by row (the padded result up to
    the rounding of the GEMMs, which run on other shapes).
    """
    if not bn.training:
        return batch_norm_rows(h, bn).relu_()
    _check_weighted_bn(bn)
    wn = rows.weight.to(h.dtype) / rows.total
    fn = _FusedWeightedBatchNormReLU if _fused_ok(h) else _WeightedBatchNormReLU
    y, mean, var = fn.apply(h, wn, bn.weight, bn.bias, bn.eps)
    _update_running_stats(bn, mean, var, rows)
    return y


class _CoordinateLinear(torch.autograd.Function):
    """``rel @ weight.T`` for coordinates rel (R, 3) with ``weight`` (C, 3): the same function as
    ``F.linear(rel, weight)``, with the weight gradient computed as ``(rel.T @ g).T``. PyTorch's
    linear backward computes ``g.T @ rel``, a GEMM whose output is only three columns wide, which MKL
    runs at 2-4 GFLOP/s on one CPU core (the slowest products of a SASA training step: about 5 % of
    it in ``DEFAULTS``); the transposed product is the same sums, 2-7x faster. Equal up to float
    summation order. The input gradient (the vote SA's votes) is ``g @ weight``, as PyTorch's."""

    @staticmethod
    def forward(ctx, rel, weight):
        ctx.save_for_backward(rel, weight)
        return rel @ weight.t()

    @staticmethod
    def backward(ctx, g):
        rel, weight = ctx.saved_tensors
        g_rel = g @ weight if ctx.needs_input_grad[0] else None
        g_weight = (rel.t() @ g).t() if ctx.needs_input_grad[1] else None
        return g_rel, g_weight


def coordinate_linear(rel: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``F.linear(rel, weight)`` (no bias) of relative coordinates rel (R, 3) in metres with weight
    (C, 3): (R, C), with a faster backward on 2-D float inputs (:class:`_CoordinateLinear`)."""
    if rel.dim() == 2 and rel.shape[1] == 3 and weight.dim() == 2 and torch.is_grad_enabled():
        return _CoordinateLinear.apply(rel, weight)
    return F.linear(rel, weight)


class GroupedMLP(nn.Module):
    """PointNet++ grouped MLP with a decomposed first layer (see module docstring).

    ``forward(xyz (B, N, 3), new_xyz (B, M, 3), features (B, N, C), idx (B, M, K), cnt (B, M))`` returns
    (B, M, w_last): max over the K neighbours of MLP([x_j - c, f_j]), zero for empty groups.

    With ``compact`` (default) the MLP runs once per distinct (centre, neighbour) pair
    (:func:`group_rows`; batch norm weighted by the multiplicities), not once per padded slot: the
    same function and gradients up to float summation order, at the cost of the hits only (a third
    to a sixth of the slots in the study's network). ``compact=False`` runs on the padded (B, M, K)
    slots and reproduces the earlier implementation bit for bit.
    """

    def __init__(self, in_ch: int, widths, compact: bool = True):
        super().__init__()
        widths = list(widths)
        if not widths:
            raise ValueError("a grouped MLP needs at least one layer")
        self.compact = bool(compact)
        self.w_xyz = nn.Linear(3, widths[0], bias=False)
        self.w_feat = nn.Linear(in_ch, widths[0], bias=False) if in_ch > 0 else None
        self.bn0 = nn.BatchNorm1d(widths[0])
        self.rest = MLP(widths[0], widths[1:])
        self.out_ch = self.rest.out_ch

    def forward(self, xyz, new_xyz, features, idx, cnt):
        """Grouped features (B, M, w_last) of the centres (see the class docstring)."""
        if self.compact:
            return self._forward_compact(xyz, new_xyz, features, idx, cnt)
        return self._forward_padded(xyz, new_xyz, features, idx, cnt)

    def _forward_padded(self, xyz, new_xyz, features, idx, cnt):
        rel = index_points(xyz, idx) - new_xyz.unsqueeze(2)  # (B, M, K, 3), metres
        h = self.w_xyz(rel)
        if self.w_feat is not None and features is not None:
            h = h + index_points(self.w_feat(features), idx)
        shape = h.shape
        h = batch_norm_rows(h.reshape(-1, shape[-1]), self.bn0).relu_().reshape(shape)
        h = self.rest(h).max(dim=2).values
        return h * (cnt > 0).to(h.dtype)[:, :, None]  # empty groups give zeros

    def _forward_compact(self, xyz, new_xyz, features, idx, cnt):
        B, N, _ = xyz.shape
        M = new_xyz.shape[1]
        rows = group_rows(idx, cnt, N)
        rel = xyz.reshape(B * N, 3).index_select(0, rows.point) - new_xyz.reshape(B * M, 3).index_select(0, rows.centre)
        h = coordinate_linear(rel, self.w_xyz.weight)  # (R, w0), metres in, features out
        if self.w_feat is not None and features is not None:
            h = h + self.w_feat(features).reshape(B * N, -1).index_select(0, rows.point)
        layers = [(None, self.bn0), *zip(self.rest.linears, self.rest.norms)]
        for lin, bn in layers[:-1]:
            h = weighted_batch_norm_relu(h if lin is None else lin(h), bn, rows)
        lin, bn = layers[-1]
        # the last layer's output, max over each centre's rows (they are contiguous); empty groups give zeros
        pooled = weighted_batch_norm_relu_max(h if lin is None else lin(h), bn, rows)
        pooled = pooled * (cnt > 0).reshape(B * M, 1).to(pooled.dtype)
        return pooled.view(B, M, -1)


class SALayer(nn.Module):
    """One set-abstraction layer with several sampling segments and multi-scale grouping.

    Args:
        in_ch: per-point feature channels C of the input (xyz not counted).
        segments: list of (npoint, lo, hi, method) with method "D-FPS" or "S-FPS": sample ``npoint``
            centres among input points [lo, hi) (hi None = all); centres are concatenated in order.
        radii: shell outer radii (m); nsamples: neighbours per shell; mlps: widths per shell.
        aggregation: output width (0: no aggregation MLP, output = concat of shells).
        confidence: segmentation branch widths (None: no branch).
        dilated: shells r_{i-1} <= d < r_i (reference DILATED_RADIUS_GROUP).
        gamma: S-FPS weight exponent.
        sampling_threads: CPU threads for sampling and ball query (see :func:`limit_threads`).
        compact: grouped MLPs on the distinct hits only (see :class:`GroupedMLP`).
    """

    def __init__(self, in_ch: int, segments, radii, nsamples, mlps, aggregation: int, confidence=None,
                 dilated: bool = True, gamma: float = 1.0, sampling_threads: int | None = 1, compact: bool = True):
        super().__init__()
        self.sampling_threads = sampling_threads
        self.segments = [(int(n), int(lo), None if hi is None else int(hi), str(m)) for n, lo, hi, m in segments]
        self.radii = [float(r) for r in radii]
        self.nsamples = [int(s) for s in nsamples]
        self.dilated = bool(dilated)
        self.gamma = float(gamma)
        self.mlps = nn.ModuleList(GroupedMLP(in_ch, widths, compact) for widths in mlps)
        out = sum(m.out_ch for m in self.mlps)
        if aggregation:
            self.aggregation, out = shared_mlp1d(out, [aggregation])
        else:
            self.aggregation = None
        self.out_ch = out
        if confidence is not None:
            body, c = shared_mlp1d(out, confidence)
            self.confidence = nn.Sequential(body, nn.Linear(c, 1, bias=True))
        else:
            self.confidence = None

    @property
    def npoint(self) -> int:
        """Centres this layer samples (all segments together)."""
        return sum(s[0] for s in self.segments)

    def sample(self, xyz: torch.Tensor, scores: torch.Tensor | None) -> torch.Tensor:
        """Centre indices (B, M) into the N input points."""
        parts = []
        for n, lo, hi, method in self.segments:
            hi_ = xyz.shape[1] if hi is None else hi
            sub = xyz[:, lo:hi_].contiguous()
            if method == "S-FPS":
                if scores is None:
                    raise ValueError("S-FPS needs the segmentation logits of the previous layer")
                idx = semantic_furthest_point_sample(sub, scores[:, lo:hi_].contiguous(), n, self.gamma)
            elif method == "D-FPS":
                idx = furthest_point_sample(sub, n)
            else:
                raise ValueError(f"unknown sampling method {method!r}")
            parts.append(idx + lo)
        return torch.cat(parts, dim=1)

    def forward(self, xyz: torch.Tensor, features: torch.Tensor | None, scores: torch.Tensor | None = None):
        """
        Args:
            xyz: (B, N, 3) point coordinates (m); features: (B, N, C) channel-last or None; scores:
                (B, N) logits of the previous layer (needed for S-FPS segments).
        Returns:
            new_xyz (B, M, 3), new_features (B, M, C_out), logits (B, M) or None, idx (B, M).
        """
        if kernels is not None and xyz.device.type == "cpu":
            # The compiled FPS / ball query run one thread per cloud, with the threads the rest of the
            # layer has (limit_threads only narrows torch's own small ops).
            kernels.parallel_chunks(torch.get_num_threads())
        with limit_threads(self.sampling_threads if xyz.device.type == "cpu" else None):
            idx = self.sample(xyz, scores)
            new_xyz = index_points(xyz, idx)
            groups = ball_query_shells(self.radii, self.nsamples, xyz, new_xyz, dilated=self.dilated)
        outs = [mlp(xyz, new_xyz, features, gidx, cnt) for (cnt, gidx), mlp in zip(groups, self.mlps)]
        new_features = torch.cat(outs, dim=-1)
        if self.aggregation is not None:
            new_features = self.aggregation(new_features)
        logits = self.confidence(new_features).squeeze(-1) if self.confidence is not None else None
        return new_xyz, new_features, logits, idx


class SASABackbone(nn.Module):
    """The three SASA layers. ``forward(xyz (B, N, 3), features (B, N, C0))`` returns a dict:

    ``xyz`` list of (B, M_l, 3) per layer, ``features`` list of (B, M_l, C_l), ``logits`` list of
    (B, M_l) or None (SA3), ``idx`` list of (B, M_l) indices into the previous layer's points, and
    ``out_xyz`` / ``out_features`` = SA3's (B, M3, 3) / (B, M3, C3).
    """

    def __init__(self, params: dict, in_features: int = 1):
        super().__init__()
        n1, n2, n3 = (int(v) for v in params["sa_npoints"])
        segs = [
            [(n1, 0, None, "D-FPS")],
            [(n2 // 2, 0, None, "S-FPS"), (n2 // 2, 0, None, "D-FPS")],
            [(n3 // 2, 0, n2 // 2, "S-FPS"), (n3 // 2, n2 // 2, n2, "D-FPS")],
        ]
        conf = list(params["sa_confidence_mlps"]) + [None]
        self.layers = nn.ModuleList()
        c = in_features
        for li in range(3):
            layer = SALayer(c, segs[li], params["sa_radii_m"][li], params["sa_nsamples"][li], params["sa_mlps"][li],
                            int(params["sa_aggregation"][li]), conf[li], params["dilated_groups"],
                            params["sfps_gamma"], params.get("sampling_threads", 1),
                            params.get("compact_groups", True))
            self.layers.append(layer)
            c = layer.out_ch
        self.out_ch = c
        self.n_candidates = n3 // 2

    def forward(self, xyz: torch.Tensor, features: torch.Tensor | None) -> dict:
        """Run the SA layers in turn (see the class docstring for the returned dict)."""
        xyzs, feats, logits, idxs = [], [], [], []
        scores = None
        for layer in self.layers:
            xyz, features, scores, idx = layer(xyz, features, scores)
            xyzs.append(xyz)
            feats.append(features)
            logits.append(scores)
            idxs.append(idx)
        return {"xyz": xyzs, "features": feats, "logits": logits, "idx": idxs, "out_xyz": xyz,
                "out_features": features}
