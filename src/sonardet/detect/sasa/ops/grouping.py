"""Ball query (plain and dilated), gather / grouping and QueryAndGroup in pure PyTorch.

Semantics follow the SASA reference (blakechen97/SASA, ``pcdet/ops/pointnet2/pointnet2_batch``:
``src/ball_query_gpu.cu`` and ``pointnet2_utils.py``):

* a query keeps the first ``nsample`` points *in index order* with ``d^2 < r^2`` (dilated:
  ``r_in^2 <= d^2 < r_out^2``), where ``d^2 = (qx-x)^2 + (qy-y)^2 + (qz-z)^2`` and ``r^2 = r * r`` are
  computed in the dtype of the coordinates;
* ``idx_cnt`` = number of hits kept (<= nsample); the remaining slots repeat the found indices
  cyclically (slot j holds hit ``j mod idx_cnt``; with one hit that is "fill with the first hit");
* an empty ball gives ``idx_cnt = 0`` and all indices 0 (the reference zero-fills its output).

Three execution strategies give identical results (tested):

* ``"compiled"`` (default on CPU when the coordinates are finite float32/float64 and Numba is
  available): the grid kernel of :mod:`.kernels` (points binned into columns at least one radius wide,
  a query tests the 3 x 3 columns around it, hits sorted by index);
* ``"tiled"`` (the CPU fallback): per cloud, queries are grouped into spatial tiles (x strips, then y
  chunks of ``chunk_size`` queries); only the points inside the tile's bounding box grown by the
  radius (plus a rounding margin, so the candidate set is a strict superset of every ball) are
  tested. Work drops roughly by the ratio of the grown tile area to the cloud area.
* ``"dense"`` (default on CUDA): chunks of ``chunk_size`` queries against all points of all clouds.

Peak memory in both is about ``16 bytes x pairs`` for a chunk, with pairs <= ``chunk_size x N`` per
cloud (tiled) or ``B x chunk_size x N`` (dense); chunks are split further to stay under
``max_pairs``.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import nn

try:  # the compiled CPU kernels are optional: without Numba the PyTorch strategies run
    from . import kernels
except ImportError:  # pragma: no cover - Numba is a dependency
    kernels = None

__all__ = [
    "ball_query",
    "ball_query_dilated",
    "ball_query_shells",
    "gather_operation",
    "grouping_operation",
    "group_with_idx",
    "index_points",
    "QueryAndGroup",
    "GroupAll",
]

_DEFAULT_CHUNK = 128  # queries per tile; 64-128 measured fastest for SA1-sized clouds on CPU
_DEFAULT_MAX_PAIRS = 1 << 23  # 8.4 M query-point pairs per distance block (~34 MB in float32)


# ----------------------------------------------------------------------------------------------
# gather / grouping (differentiable w.r.t. features through torch.gather)
# ----------------------------------------------------------------------------------------------
def gather_operation(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Gather per-point features at sampled indices (reference ``gather_operation``).

    Args:
        features: (B, C, N) tensor.
        idx: (B, M) integer tensor of indices into N (any integer dtype, same device).

    Returns:
        (B, C, M) tensor, ``out[b, c, m] = features[b, c, idx[b, m]]``. Differentiable w.r.t.
        ``features`` (the backward scatters-adds, like the reference ``gather_points_grad``).
    """
    if features.dim() != 3 or idx.dim() != 2 or idx.shape[0] != features.shape[0]:
        raise ValueError(f"expected features (B,C,N) and idx (B,M), got {tuple(features.shape)}, {tuple(idx.shape)}")
    B, C, _ = features.shape
    index = idx.long().unsqueeze(1).expand(B, C, idx.shape[1])
    return torch.gather(features, 2, index)


def grouping_operation(features: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Group per-point features by neighbour indices (reference ``grouping_operation``).

    Args:
        features: (B, C, N) tensor.
        idx: (B, M, K) integer tensor of indices into N (e.g. from :func:`ball_query`).

    Returns:
        (B, C, M, K) tensor, ``out[b, c, m, k] = features[b, c, idx[b, m, k]]``; differentiable
        w.r.t. ``features``.
    """
    if features.dim() != 3 or idx.dim() != 3 or idx.shape[0] != features.shape[0]:
        raise ValueError(f"expected features (B,C,N) and idx (B,M,K), got {tuple(features.shape)}, {tuple(idx.shape)}")
    B, C, _ = features.shape
    _, M, K = idx.shape
    index = idx.long().reshape(B, 1, M * K).expand(B, C, M * K)
    return torch.gather(features, 2, index).view(B, C, M, K)


def index_points(points: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Channel-last gather: rows of ``points`` (B, N, D) at ``idx`` (B, *S) -> (B, *S, D).

    Convenience for coordinates, e.g. ``new_xyz = index_points(xyz, fps_idx)`` gives (B, M, 3).
    Differentiable w.r.t. ``points``.
    """
    B, _, D = points.shape
    flat = idx.long().reshape(B, -1, 1).expand(B, -1, D)
    return torch.gather(points, 1, flat).view(*idx.shape, D)


# ----------------------------------------------------------------------------------------------
# ball query
# ----------------------------------------------------------------------------------------------
def _check_query_inputs(xyz: torch.Tensor, new_xyz: torch.Tensor, nsample: int) -> None:
    if xyz.dim() != 3 or xyz.shape[-1] != 3:
        raise ValueError(f"xyz must be (B, N, 3), got {tuple(xyz.shape)}")
    if new_xyz.dim() != 3 or new_xyz.shape[-1] != 3 or new_xyz.shape[0] != xyz.shape[0]:
        raise ValueError(f"new_xyz must be (B, M, 3) with the batch size of xyz, got {tuple(new_xyz.shape)}")
    if not xyz.is_floating_point():
        raise TypeError(f"xyz must be floating point, got {xyz.dtype}")
    if new_xyz.device != xyz.device:
        raise ValueError(f"xyz on {xyz.device} but new_xyz on {new_xyz.device}")
    if nsample < 1:
        raise ValueError(f"nsample must be >= 1, got {nsample}")


def _first_k(mask: torch.Tensor, nsample: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per row of a (R, C) bool mask: first ``nsample`` true columns in order, cyclically padded.

    Returns (cols (R, nsample) int64, cnt (R,) int64); rows without hits get cols 0 and cnt 0.
    """
    R = mask.shape[0]
    rows, cols = mask.nonzero(as_tuple=True)  # row-major: columns ascending within a row
    counts = torch.bincount(rows, minlength=R) if rows.numel() else torch.zeros(R, dtype=torch.long, device=mask.device)
    start = torch.cumsum(counts, 0) - counts
    rank = torch.arange(rows.numel(), device=mask.device) - start[rows]
    keep = rank < nsample
    out = torch.zeros((R, nsample), dtype=torch.long, device=mask.device)
    out[rows[keep], rank[keep]] = cols[keep]
    cnt = counts.clamp(max=nsample)
    slot = torch.arange(nsample, device=mask.device)
    src = slot.unsqueeze(0) % cnt.clamp(min=1).unsqueeze(1)  # cyclic padding (identity when full)
    return out.gather(1, src), cnt


def _sq_dist(q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Squared distances (..., Mq, Np) between q (..., Mq, 3) and p (..., Np, 3), reference op order."""
    d = q[..., :, None, 0] - p[..., None, :, 0]
    d = d * d
    t = q[..., :, None, 1] - p[..., None, :, 1]
    d += t * t
    t = q[..., :, None, 2] - p[..., None, :, 2]
    d += t * t
    return d


def _shell_mask(d2: torch.Tensor, r_in2: torch.Tensor | None, r_out2: torch.Tensor) -> torch.Tensor:
    m = d2 < r_out2
    if r_in2 is not None:
        m &= d2 >= r_in2
    return m


def _sq_radius(r: float, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    rt = torch.tensor(float(r), dtype=dtype, device=device)
    return rt * rt  # reference: float radius2 = radius * radius


def _tile_queries(q: torch.Tensor, chunk_size: int) -> list[torch.Tensor]:
    """Split query indices of one cloud (M, 3) into spatially compact chunks of <= chunk_size."""
    M = q.shape[0]
    if M <= chunk_size:
        return [torch.arange(M, device=q.device)]
    n_chunks = math.ceil(M / chunk_size)
    n_strips = max(1, int(round(math.sqrt(n_chunks))))
    by_x = torch.argsort(q[:, 0])
    chunks = []
    for strip in torch.tensor_split(by_x, n_strips):
        strip = strip[torch.argsort(q[strip, 1])]
        chunks.extend(torch.split(strip, chunk_size))
    return chunks


def _empty_shell_outputs(B: int, M: int, shells, device) -> list:
    """Per shell (r_in2, r_out2, nsample, r): zero counts (B, M) and zero indices (B, M, nsample), int64:
    what an empty ball returns, filled in by the query."""
    return [(torch.zeros((B, M), dtype=torch.long, device=device),
             torch.zeros((B, M, ns), dtype=torch.long, device=device)) for _, _, ns, _ in shells]


def _ball_query_tiled(xyz, new_xyz, shells, chunk_size, max_pairs):
    B, N, _ = xyz.shape
    M = new_xyz.shape[1]
    device = xyz.device
    outs = _empty_shell_outputs(B, M, shells, device)
    r_max = max(s[3] for s in shells)
    for b in range(B):
        p = xyz[b]
        q_all = new_xyz[b]
        finite = torch.isfinite(p).all() and torch.isfinite(q_all).all()
        scale = float(torch.cat([p.abs().max().reshape(1), q_all.abs().max().reshape(1)]).max()) if finite else 0.0
        if not finite:
            tiles = torch.split(torch.arange(M, device=device), chunk_size)
        else:
            tiles = _tile_queries(q_all, chunk_size)
        # Rounding margin: a point outside the grown box is outside every ball even in floating point.
        margin = r_max * (1.0 + 1e-3) + 1e-5 * (1.0 + scale)
        px_sorted, perm_x = torch.sort(p[:, 0])
        for qi in tiles:
            q = q_all[qi]
            if finite:
                lo_hi = torch.stack([q[:, 0].min() - margin, q[:, 0].max() + margin])
                lo, hi = torch.searchsorted(px_sorted, lo_hi).tolist()
                cand = perm_x[lo:hi]
                cy = p[cand, 1]
                cz = p[cand, 2]
                keep = (cy >= q[:, 1].min() - margin) & (cy <= q[:, 1].max() + margin)
                keep &= (cz >= q[:, 2].min() - margin) & (cz <= q[:, 2].max() + margin)
                cand = torch.sort(cand[keep]).values  # index order matters: first hits by index
            else:  # NaN/Inf present: no pruning, every point is a candidate
                cand = torch.arange(N, device=device)
            if cand.numel() == 0:
                continue  # every ball empty: zeros already in place
            pc = p[cand]
            step = max(1, max_pairs // cand.numel())
            for s0 in range(0, qi.numel(), step):
                qs = qi[s0:s0 + step]
                d2 = _sq_dist(q_all[qs], pc)
                for k, (r_in2, r_out2, ns, _) in enumerate(shells):
                    cols, cnt = _first_k(_shell_mask(d2, r_in2, r_out2), ns)
                    outs[k][0][b, qs] = cnt
                    # empty balls keep index 0 (not the first candidate's index)
                    outs[k][1][b, qs] = torch.where(cnt[:, None] > 0, cand[cols], 0)
    return outs


def _ball_query_dense(xyz, new_xyz, shells, chunk_size, max_pairs):
    B, N, _ = xyz.shape
    M = new_xyz.shape[1]
    device = xyz.device
    outs = _empty_shell_outputs(B, M, shells, device)
    step = max(1, min(chunk_size, max_pairs // max(1, B * N)))
    for m0 in range(0, M, step):
        q = new_xyz[:, m0:m0 + step]  # (B, Mc, 3)
        d2 = _sq_dist(q, xyz)  # (B, Mc, N)
        Mc = q.shape[1]
        for k, (r_in2, r_out2, ns, _) in enumerate(shells):
            cols, cnt = _first_k(_shell_mask(d2, r_in2, r_out2).view(B * Mc, N), ns)
            outs[k][0][:, m0:m0 + Mc] = cnt.view(B, Mc)
            outs[k][1][:, m0:m0 + Mc] = cols.view(B, Mc, ns)
    return outs


@torch.no_grad()
def ball_query_shells(
    radii: Sequence[float],
    nsamples: Sequence[int],
    xyz: torch.Tensor,
    new_xyz: torch.Tensor,
    dilated: bool = False,
    chunk_size: int = _DEFAULT_CHUNK,
    method: str = "auto",
    max_pairs: int = _DEFAULT_MAX_PAIRS,
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """Several ball queries around the same centres sharing one distance computation.

    The multi-scale grouping of an SA layer: for radius ``radii[i]`` (m, increasing when
    ``dilated``) keep up to ``nsamples[i]`` points with ``d < radii[i]``, or with ``dilated=True`` the
    shell ``radii[i-1] <= d < radii[i]`` (``radii[-1] := 0``), exactly as calling
    :func:`ball_query` / :func:`ball_query_dilated` once per radius.

    Args:
        radii: radii in the units of ``xyz`` (m), each > 0.
        nsamples: max neighbours per radius.
        xyz: (B, N, 3) float point coordinates.
        new_xyz: (B, M, 3) query centres (same dtype and device).
        dilated: shells instead of balls (SASA/3DSSD ``DILATED_RADIUS_GROUP``).
        chunk_size: queries per distance block (bounds memory, see module docstring).
        method: ``"compiled"``, ``"tiled"``, ``"dense"`` or ``"auto"`` (compiled on CPU where it
            applies, else tiled; dense elsewhere).
        max_pairs: upper bound on query-point pairs per distance block.

    Returns:
        list of ``(idx_cnt, idx)`` per radius, in reference order: ``idx_cnt`` (B, M) int64 number of
        hits kept, ``idx`` (B, M, nsample_i) int64 indices into N.
    """
    if len(radii) != len(nsamples) or len(radii) == 0:
        raise ValueError("radii and nsamples must be non-empty and of equal length")
    shells = []
    prev = 0.0
    for r, ns in zip(radii, nsamples):
        if dilated:
            shells.append((float(prev), float(r), int(ns)))
            prev = r
        else:
            shells.append((None, float(r), int(ns)))
    return _ball_query_impl(shells, xyz, new_xyz, chunk_size, method, max_pairs)


def _ball_query_impl(shells, xyz, new_xyz, chunk_size, method, max_pairs):
    for _, _, ns in shells:
        _check_query_inputs(xyz, new_xyz, ns)
    if chunk_size < 1:
        raise ValueError(f"chunk_size must be >= 1, got {chunk_size}")
    xyz = xyz.detach()
    new_xyz = new_xyz.detach().to(xyz.dtype)
    dt, dev = xyz.dtype, xyz.device
    prepared = []
    for r_in, r_out, ns in shells:
        if r_out <= 0 or (r_in is not None and r_in < 0):
            raise ValueError(f"radii must be positive, got r_in={r_in}, r_out={r_out}")
        r_in2 = None if r_in is None else _sq_radius(r_in, dt, dev)
        prepared.append((r_in2, _sq_radius(r_out, dt, dev), ns, r_out))
    B, N, _ = xyz.shape
    M = new_xyz.shape[1]
    if N == 0 or M == 0 or B == 0:
        return [
            (torch.zeros((B, M), dtype=torch.long, device=dev), torch.zeros((B, M, ns), dtype=torch.long, device=dev))
            for _, _, ns in shells
        ]
    if method == "auto":
        method = "tiled" if xyz.device.type == "cpu" else "dense"
        if method == "tiled" and _compiled_ok(xyz, new_xyz):
            method = "compiled"
    if method == "compiled":
        if not _compiled_ok(xyz, new_xyz):
            raise ValueError("method 'compiled' needs finite float32/float64 CPU tensors and Numba")
        return _ball_query_compiled(xyz, new_xyz, prepared)
    if method == "tiled":
        return _ball_query_tiled(xyz, new_xyz, prepared, chunk_size, max_pairs)
    if method == "dense":
        return _ball_query_dense(xyz, new_xyz, prepared, chunk_size, max_pairs)
    raise ValueError(f"method must be 'auto', 'compiled', 'tiled' or 'dense', got {method!r}")


def _compiled_ok(xyz: torch.Tensor, new_xyz: torch.Tensor) -> bool:
    """Whether the compiled kernel applies: CPU, float32/float64, finite coordinates, Numba available."""
    if kernels is None or xyz.device.type != "cpu" or xyz.dtype not in (torch.float32, torch.float64):
        return False
    return bool(torch.isfinite(xyz).all()) and bool(torch.isfinite(new_xyz).all())


def _ball_query_compiled(xyz, new_xyz, shells):
    """The shells through :func:`.kernels.ball_query_kernel`; [(idx_cnt (B, M), idx (B, M, ns))] per shell."""
    dt = xyz.dtype
    r_in2 = torch.stack([torch.tensor(-math.inf, dtype=dt) if s[0] is None else s[0].cpu() for s in shells])
    r_out2 = torch.stack([s[1].cpu() for s in shells])
    ns = torch.tensor([s[2] for s in shells], dtype=torch.long)
    x = xyz.contiguous()
    scale = float(torch.maximum(x.abs().max(), new_xyz.abs().max()))
    span = x[..., :2].amax(dim=1) - x[..., :2].amin(dim=1)  # (B, 2) xy extent per cloud
    cell = kernels.grid_cell(max(s[3] for s in shells), scale, x.shape[1], float(span.max()))
    idx, cnt = kernels.ball_query_kernel(x.numpy(), new_xyz.contiguous().numpy(), r_in2.numpy(), r_out2.numpy(),
                                         ns.numpy(), cell)
    idx, cnt = torch.from_numpy(idx), torch.from_numpy(cnt)
    out, off = [], 0
    for k, (_, _, n, _) in enumerate(shells):
        out.append((cnt[:, :, k].contiguous(), idx[:, :, off:off + n].contiguous()))
        off += n
    return out


@torch.no_grad()
def ball_query(
    radius: float,
    nsample: int,
    xyz: torch.Tensor,
    new_xyz: torch.Tensor,
    chunk_size: int = _DEFAULT_CHUNK,
    return_count: bool = False,
    method: str = "auto",
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Ball query: for each centre the first ``nsample`` points (index order) with ``d < radius``.

    Reference semantics (module docstring): cyclic padding with the found indices; an empty ball
    gives all-zero indices and count 0.

    Args:
        radius: ball radius in the units of ``xyz`` (m), > 0.
        nsample: max neighbours K >= 1.
        xyz: (B, N, 3) float point coordinates.
        new_xyz: (B, M, 3) centres.
        chunk_size: queries per distance block (memory bound, see module docstring).
        return_count: also return the hit counts.
        method: ``"auto"``, ``"compiled"``, ``"tiled"`` or ``"dense"`` (identical results).

    Returns:
        ``idx`` (B, M, K) int64 indices into N, or ``(idx_cnt, idx)`` with ``idx_cnt`` (B, M) int64
        when ``return_count`` (the reference's order).
    """
    (cnt, idx), = _ball_query_impl([(None, float(radius), int(nsample))], xyz, new_xyz, chunk_size, method,
                                   _DEFAULT_MAX_PAIRS)
    return (cnt, idx) if return_count else idx


@torch.no_grad()
def ball_query_dilated(
    radius_in: float,
    radius_out: float,
    nsample: int,
    xyz: torch.Tensor,
    new_xyz: torch.Tensor,
    chunk_size: int = _DEFAULT_CHUNK,
    return_count: bool = False,
    method: str = "auto",
) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
    """Dilated ball query: first ``nsample`` points (index order) with ``radius_in <= d < radius_out``.

    The reference ``ball_query_dilated`` (3DSSD/SASA ``DILATED_RADIUS_GROUP``); padding and empty
    shells as in :func:`ball_query`. ``radius_in = 0`` is the plain ball query.

    Args:
        radius_in: inner radius (m), >= 0, inclusive.
        radius_out: outer radius (m), > 0, exclusive.
        nsample: max neighbours K >= 1.
        xyz: (B, N, 3) float point coordinates.
        new_xyz: (B, M, 3) centres.
        chunk_size, return_count, method: as in :func:`ball_query`.

    Returns:
        ``idx`` (B, M, K) int64, or ``(idx_cnt, idx)`` when ``return_count``.
    """
    (cnt, idx), = _ball_query_impl([(float(radius_in), float(radius_out), int(nsample))], xyz, new_xyz,
                                   chunk_size, method, _DEFAULT_MAX_PAIRS)
    return (cnt, idx) if return_count else idx


# ----------------------------------------------------------------------------------------------
# QueryAndGroup
# ----------------------------------------------------------------------------------------------
class QueryAndGroup(nn.Module):
    """Ball query + grouping of relative coordinates and features (reference ``QueryAndGroup`` and
    ``QueryAndGroupDilated``).

    Args:
        radius: ball radius (m); with ``radius_in`` the outer shell radius.
        nsample: neighbours per centre K.
        use_xyz: put the 3 relative-coordinate channels in front of the grouped features.
        normalize_xyz: divide the relative coordinates by ``radius`` (unitless in [-1, 1]); the SASA
            reference does not (False).
        radius_in: inner radius (m) for a dilated shell query, None for a ball.
        chunk_size: forwarded to the ball query.
    """

    def __init__(self, radius: float, nsample: int, use_xyz: bool = True, normalize_xyz: bool = False,
                 radius_in: float | None = None, chunk_size: int = _DEFAULT_CHUNK):
        super().__init__()
        self.radius, self.nsample, self.use_xyz = float(radius), int(nsample), use_xyz
        self.normalize_xyz, self.radius_in, self.chunk_size = normalize_xyz, radius_in, chunk_size

    def extra_repr(self) -> str:
        return (f"radius={self.radius}, nsample={self.nsample}, use_xyz={self.use_xyz}, "
                f"normalize_xyz={self.normalize_xyz}, radius_in={self.radius_in}")

    def forward(self, xyz: torch.Tensor, new_xyz: torch.Tensor, features: torch.Tensor | None = None):
        """Group neighbours of each centre.

        Args:
            xyz: (B, N, 3) point coordinates (m).
            new_xyz: (B, M, 3) centres (m).
            features: (B, C, N) per-point features or None.

        Returns:
            ``(idx_cnt, new_features)`` as the reference: ``idx_cnt`` (B, M) int64 hit counts and
            ``new_features`` (B, 3 + C, M, K) (or (B, C, M, K) without ``use_xyz``; (B, 3, M, K) without
            features) whose first 3 channels are neighbour minus centre (m, or / radius if
            ``normalize_xyz``). Differentiable w.r.t. ``features``, ``xyz`` and ``new_xyz``.
        """
        if self.radius_in is None:
            idx_cnt, idx = ball_query(self.radius, self.nsample, xyz, new_xyz, self.chunk_size, return_count=True)
        else:
            idx_cnt, idx = ball_query_dilated(self.radius_in, self.radius, self.nsample, xyz, new_xyz,
                                              self.chunk_size, return_count=True)
        return idx_cnt, group_with_idx(xyz, new_xyz, features, idx, self.use_xyz,
                                       self.radius if self.normalize_xyz else None)


def group_with_idx(xyz: torch.Tensor, new_xyz: torch.Tensor, features: torch.Tensor | None, idx: torch.Tensor,
                   use_xyz: bool = True, normalize_radius: float | None = None) -> torch.Tensor:
    """Grouped relative xyz (+ features) for precomputed neighbour indices.

    Args:
        xyz: (B, N, 3); new_xyz: (B, M, 3); features: (B, C, N) or None; idx: (B, M, K).
        use_xyz: include the relative-coordinate channels.
        normalize_radius: divide relative coordinates by this radius (m) if given.

    Returns:
        (B, 3 + C, M, K) (channels as in :class:`QueryAndGroup`).
    """
    parts = []
    if use_xyz or features is None:
        if not use_xyz:
            raise ValueError("features is None and use_xyz is False: nothing to group")
        grouped_xyz = grouping_operation(xyz.transpose(1, 2), idx)  # (B, 3, M, K)
        grouped_xyz = grouped_xyz - new_xyz.transpose(1, 2).unsqueeze(-1)
        if normalize_radius is not None:
            grouped_xyz = grouped_xyz / normalize_radius
        parts.append(grouped_xyz)
    if features is not None:
        parts.append(grouping_operation(features, idx))
    return parts[0] if len(parts) == 1 else torch.cat(parts, dim=1)


class GroupAll(nn.Module):
    """Group every point around a single centre (reference ``GroupAll``; centre at the origin).

    forward(xyz (B, N, 3), new_xyz ignored, features (B, C, N) or None) returns
    ``(idx_cnt (B, 1) of ones, new_features (B, 3 + C, 1, N))`` (absolute xyz, as the reference).
    """

    def __init__(self, use_xyz: bool = True):
        super().__init__()
        self.use_xyz = use_xyz

    def forward(self, xyz: torch.Tensor, new_xyz: torch.Tensor | None = None, features: torch.Tensor | None = None):
        grouped_xyz = xyz.transpose(1, 2).unsqueeze(2)
        if features is None:
            new_features = grouped_xyz
        elif self.use_xyz:
            new_features = torch.cat([grouped_xyz, features.unsqueeze(2)], dim=1)
        else:
            new_features = features.unsqueeze(2)
        idx_cnt = torch.ones((xyz.shape[0], 1), dtype=torch.long, device=xyz.device)
        return idx_cnt, new_features
