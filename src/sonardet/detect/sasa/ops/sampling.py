"""Furthest point sampling (D-FPS) and semantics-guided FPS (S-FPS) in pure PyTorch.

Hand-written because no maintained library offers the weighted variant (DESIGN.md section 4). The
functions replicate the CUDA kernels of the SASA reference (blakechen97/SASA,
``pcdet/ops/pointnet2/pointnet2_batch/src/sampling_gpu.cu``: ``furthest_point_sampling_kernel`` and
``furthest_point_sampling_weights_kernel``) step by step, including how they break ties:

* the kernel runs one block of ``T = min(2**floor(log2 N), 1024)`` threads per cloud; thread ``t``
  scans the indices ``t, t + T, t + 2T, ...`` and keeps the *first* index with the largest value
  (strict ``>``); the block then reduces the thread results with a tree (strides T/2, ..., 1) that
  keeps the lower slot on equality. Among equal values the winner is therefore the index ``k`` with
  the smallest ``(bitreverse(k mod T), k // T)``.
* here the points are permuted once into exactly that preference order, so that ``torch.argmax``
  (which returns the first maximal index) reproduces the reference choice with no per-step cost.

On CPU, with finite coordinates and weights in float32/float64, the compiled block algorithm of
:mod:`.kernels` does the sampling (same indices, same float arithmetic; it skips the blocks of points
that the last pick cannot reach). On CUDA, under the same conditions and for clouds of at most
:data:`.gpu_kernels.MAX_POINTS` points, the Triton kernel of :mod:`.gpu_kernels` does it (one program
per cloud, the cloud held in registers; same indices). Otherwise (non-finite values, Numba or Triton
missing, larger clouds on CUDA) the PyTorch loop below runs on the device of the input: one Python
step per sampled point, vectorised over batch and points (O(npoint * B * N) work, O(B * N) memory).
All three give the same indices (tested; the Triton kernel on a GPU).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import torch

try:  # the compiled CPU kernels are optional: without Numba the PyTorch loop runs everywhere
    from . import kernels
except ImportError:  # pragma: no cover - Numba is a dependency
    kernels = None

__all__ = [
    "furthest_point_sample",
    "weighted_furthest_point_sample",
    "semantic_furthest_point_sample",
    "fps_block_size",
]

# Initial value of the running min-distance buffer in the reference (``temp.fill_(1e10)``).
_TEMP_INIT = 1e10
# Lower clamp of the weights in the reference S-FPS kernel (``max(weights[k], 1e-12)``).
_WEIGHT_MIN = 1e-12
# Two-level argmax: group width and the smallest B * N where it beats torch.argmax.
_GROUP = 64
_HIER_MIN = 1 << 14


def fps_block_size(n: int) -> int:
    """CUDA block size the reference FPS kernels use for a cloud of ``n`` points.

    Replicates ``opt_n_threads`` of the reference ``cuda_utils.h``:
    ``min(2 ** int(log(n) / log(2)), 1024)`` computed in double precision, at least 1.
    """
    if n < 1:
        return 1
    pow2 = int(math.log(float(n)) / math.log(2.0))
    return max(min(1 << pow2, 1024), 1)


@lru_cache(maxsize=64)
def _preference_order_cpu(n: int) -> torch.Tensor:
    """Indices 0..n-1 sorted by the reference kernel's tie-break preference (most preferred first)."""
    block = fps_block_size(n)
    bits = block.bit_length() - 1
    k = torch.arange(n, dtype=torch.long)
    tid = k % block
    rev = torch.zeros_like(tid)
    for b in range(bits):
        rev |= ((tid >> b) & 1) << (bits - 1 - b)
    per_thread = -(-n // block)  # ceil(n / block): max number of indices one thread scans
    key = rev * per_thread + k // block
    order = torch.argsort(key)
    # Index 0 is always the most preferred one (rev = 0, k // T = 0): the D-FPS seed keeps position 0.
    assert n == 0 or int(order[0]) == 0
    return order


def _preference_order(n: int, device: torch.device) -> torch.Tensor:
    return _preference_order_cpu(n).to(device)


def _check_xyz(xyz: torch.Tensor) -> None:
    if not isinstance(xyz, torch.Tensor) or xyz.dim() != 3 or xyz.shape[-1] != 3:
        raise ValueError(f"xyz must be a (B, N, 3) tensor, got {getattr(xyz, 'shape', type(xyz))}")
    if not xyz.is_floating_point():
        raise TypeError(f"xyz must be a floating-point tensor, got {xyz.dtype}")
    if xyz.shape[1] < 1:
        raise ValueError("xyz has no points (N == 0): cannot sample from an empty cloud")


def _fps_loop(xyz: torch.Tensor, npoint: int, weights: torch.Tensor | None) -> torch.Tensor:
    """Shared D-FPS / weighted-FPS entry; see the public functions for the contract."""
    _check_xyz(xyz)
    if npoint < 0:
        raise ValueError(f"npoint must be >= 0, got {npoint}")
    B, N, _ = xyz.shape
    device = xyz.device
    if npoint == 0:
        return torch.zeros((B, 0), dtype=torch.long, device=device)
    order = _preference_order(N, device)
    xp = xyz.detach().index_select(1, order)  # (B, N, 3), points in preference order
    wp = None if weights is None else weights.detach().to(xp.dtype).index_select(1, order)
    n_iter = min(npoint, N)
    if _compiled_ok(xp, wp):
        picked = _fps_compiled(xp, wp, n_iter)
    elif xp.device.type == "cuda" and _gpu_kernels().usable(xp, wp):
        picked = _fps_gpu(xp, wp, n_iter)
    else:
        picked = _fps_torch(xp, wp, n_iter)
    idx = order[picked]  # back to original indices
    if npoint > N:
        # Deviation (documented): cyclic repetition of the N-long sequence, see furthest_point_sample.
        idx = idx[:, torch.arange(npoint, device=device) % N]
    return idx


def _compiled_ok(xp: torch.Tensor, wp: torch.Tensor | None) -> bool:
    """Whether the compiled kernel applies: CPU, float32/float64, finite values, Numba available."""
    if kernels is None or xp.device.type != "cpu" or xp.dtype not in (torch.float32, torch.float64):
        return False
    return bool(torch.isfinite(xp).all()) and (wp is None or bool(torch.isfinite(wp).all()))


def _fps_compiled(xp: torch.Tensor, wp: torch.Tensor | None, n_iter: int) -> torch.Tensor:
    """Preference positions (B, n_iter) picked by the compiled block FPS (:func:`.kernels.fps_kernel`)."""
    x = xp.contiguous().numpy()
    if wp is None:
        w = np.zeros((1, 1), x.dtype)
        out = kernels.fps_kernel(x, w, w, n_iter, False)
    else:
        # The score factor exactly as the PyTorch loop computes it (clamp in the dtype of xyz).
        out = kernels.fps_kernel(x, wp.contiguous().numpy(), wp.clamp_min(_WEIGHT_MIN).contiguous().numpy(),
                                 n_iter, True)
    return torch.from_numpy(out)


def _gpu_kernels():
    """The Triton kernels' module, imported on the first CUDA input (it imports Triton)."""
    from . import gpu_kernels

    return gpu_kernels


def _fps_gpu(xp: torch.Tensor, wp: torch.Tensor | None, n_iter: int) -> torch.Tensor:
    """Preference positions (B, n_iter) picked by the Triton kernel (:func:`.gpu_kernels.fps_triton`)."""
    fps_triton = _gpu_kernels().fps_triton
    if wp is None:  # reference: the first pick is index 0, position 0 of the permuted cloud
        return fps_triton(xp, None, torch.zeros(xp.shape[0], dtype=torch.long, device=xp.device), n_iter)
    # The first pick and the score factor exactly as the PyTorch loop computes them.
    return fps_triton(xp, wp.clamp_min(_WEIGHT_MIN), wp.argmax(dim=1), n_iter)


def _fps_torch(xp: torch.Tensor, wp: torch.Tensor | None, n_iter: int) -> torch.Tensor:
    """Preference positions (B, n_iter) picked by the vectorised PyTorch loop (any device)."""
    B, N, _ = xp.shape
    device = xp.device
    flat = xp.reshape(B * N, 3)
    base = torch.arange(B, device=device) * N

    # Two-level argmax (max per group of _GROUP, then inside the winning group) is several times
    # faster than torch.argmax on large rows and returns the same first maximum. Rows are padded to
    # a multiple of _GROUP with points at +inf whose running distance stays -1, so they never win.
    hier = B * N >= _HIER_MIN
    Np = -(-N // _GROUP) * _GROUP if hier else N
    pad = Np - N
    # Structure-of-arrays copies: each coordinate row is contiguous for the per-step update.
    x, y, z = (torch.nn.functional.pad(xp[..., i], (0, pad), value=math.inf) for i in range(3))

    picked = torch.empty((B, n_iter), dtype=torch.long, device=device)
    temp = torch.full((B, Np), _TEMP_INIT, dtype=xp.dtype, device=device)
    temp[:, N:] = -1.0
    d = torch.empty_like(temp)
    t = torch.empty_like(temp)
    rows = torch.arange(B, device=device)

    def first_argmax(v: torch.Tensor) -> torch.Tensor:
        if not hier:
            return v.argmax(dim=1)
        g = v.view(B, Np // _GROUP, _GROUP)
        blk = g.amax(dim=2).argmax(dim=1)
        return blk * _GROUP + g[rows, blk].argmax(dim=1)

    if wp is None:
        # Reference: idxs[0] = 0; position 0 of the permuted cloud is original index 0.
        old = torch.zeros(B, dtype=torch.long, device=device)
        w_clamped = None
        score = temp
    else:
        # Reference round j == 0: the point of largest (unclamped) weight, same tie rule.
        old = wp.argmax(dim=1)
        w_clamped = torch.nn.functional.pad(wp.clamp_min(_WEIGHT_MIN), (0, pad), value=1.0)
        score = torch.empty_like(temp)
    picked[:, 0] = old

    for j in range(1, n_iter):
        p = flat.index_select(0, base + old)  # (B, 3) last picked point
        # d = (x - x1)^2 + (y - y1)^2 + (z - z1)^2, same operation order as the kernel.
        torch.sub(x, p[:, 0:1], out=d)
        d.mul_(d)
        torch.sub(y, p[:, 1:2], out=t)
        t.mul_(t)
        d.add_(t)
        torch.sub(z, p[:, 2:3], out=t)
        t.mul_(t)
        d.add_(t)
        torch.minimum(temp, d, out=temp)
        if w_clamped is not None:
            torch.mul(temp, w_clamped, out=score)
        old = first_argmax(score)  # first maximum == reference tie-break in this order
        picked[:, j] = old
    return picked


@torch.no_grad()
def furthest_point_sample(xyz: torch.Tensor, npoint: int) -> torch.Tensor:
    """D-FPS: iterative furthest point sampling on squared Euclidean distance.

    Starts at index 0; each later step picks the point with the largest squared distance (in the
    units of ``xyz``, m^2 for metres) to the already chosen set, ties broken exactly as the reference
    CUDA kernel does (see the module docstring). Distances are computed in the dtype of ``xyz``;
    the running minimum starts at 1e10 as in the reference, so centre real-world coordinates first.

    Args:
        xyz: (B, N, 3) float tensor of point coordinates (any device), N >= 1.
        npoint: number of samples M >= 0.

    Returns:
        (B, M) int64 tensor of indices into dim 1 of ``xyz``, on the device of ``xyz``.

    Edge cases:
        * duplicate points / fewer distinct points than ``npoint``: once every distinct location is
          chosen all distances are 0 and, like the reference, the tie rule returns index 0 for the
          remaining steps.
        * ``npoint > N`` (the reference has no rule; its kernel would continue with index 0): the
          first N indices are the FPS order (a permutation of all points if they are distinct),
          followed by that sequence repeated cyclically, so every point appears ``npoint // N`` or
          ``npoint // N + 1`` times.
        * ``N == 1``: all zeros.
    """
    return _fps_loop(xyz, int(npoint), None)


@torch.no_grad()
def weighted_furthest_point_sample(xyz: torch.Tensor, weights: torch.Tensor, npoint: int) -> torch.Tensor:
    """Weighted FPS, the reference ``furthest_point_sample_weights`` kernel.

    Step 0 picks ``argmax(weights)``; each later step updates the running minimum squared distance
    ``temp`` (m^2) to the chosen set and picks ``argmax(temp * max(weights, 1e-12))``. Ties, npoint > N
    and duplicate points are handled as in :func:`furthest_point_sample`.

    Args:
        xyz: (B, N, 3) float tensor of point coordinates, N >= 1.
        weights: (B, N) non-negative per-point weights (same device), e.g. ``sigmoid(logit) ** gamma``.
        npoint: number of samples M >= 0.

    Returns:
        (B, M) int64 indices into dim 1 of ``xyz``.
    """
    _check_xyz(xyz)
    if weights.shape != xyz.shape[:2]:
        raise ValueError(f"weights must have shape {tuple(xyz.shape[:2])}, got {tuple(weights.shape)}")
    return _fps_loop(xyz, int(npoint), weights)


@torch.no_grad()
def semantic_furthest_point_sample(
    xyz: torch.Tensor, scores: torch.Tensor, npoint: int, gamma: float = 1.0
) -> torch.Tensor:
    """S-FPS (SASA semantics-guided FPS) driven by per-point foreground *logits*.

    As in the reference ``_PointnetSAModuleFSBase`` + ``furthest_point_sample_weights``:
    ``w = sigmoid(scores) ** gamma`` (computed in the dtype of ``xyz``), the first sample is
    ``argmax(w)`` and each later one maximises ``min_dist^2 * max(w, 1e-12)``. With ``gamma = 0`` all
    weights are 1 and the result equals :func:`furthest_point_sample` exactly (same start at index 0
    through the tie rule).

    Args:
        xyz: (B, N, 3) float tensor of point coordinates (m), N >= 1.
        scores: (B, N) foreground logits (unbounded real numbers, not probabilities).
        npoint: number of samples M >= 0.
        gamma: exponent of the sigmoid weight (reference ``WEIGHT_GAMMA``, default 1.0).

    Returns:
        (B, M) int64 indices into dim 1 of ``xyz``.
    """
    _check_xyz(xyz)
    if scores.shape != xyz.shape[:2]:
        raise ValueError(f"scores must have shape {tuple(xyz.shape[:2])}, got {tuple(scores.shape)}")
    weights = torch.sigmoid(scores.detach().to(xyz.dtype)) ** gamma
    return _fps_loop(xyz, int(npoint), weights)
