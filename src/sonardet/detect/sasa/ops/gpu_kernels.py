"""A Triton kernel for furthest point sampling on CUDA (D-FPS and weighted FPS / S-FPS).

Why hand-written: on CUDA the PyTorch loop of :mod:`.sampling` issues a dozen kernel launches per
sampled point (4096 + 1024 + 512 picks per cloud in the study preset), so the sampling is bound by
launch latency, not by the GPU. Neither PyTorch nor a maintained library ships a weighted FPS with
the reference's tie rule; the reference's own CUDA extension needs a build step we do not want.

:func:`fps_triton` runs one program per cloud and keeps the whole cloud (at most
``MAX_POINTS`` points, already permuted into the reference's preference order by the caller) and its
running distance in registers for all the picks. Each pick computes
``((x - x1)^2 + (y - y1)^2) + (z - z1)^2`` with one rounding per operation (``enable_fp_fusion`` off:
no fused multiply-add, exactly the PyTorch loop's and the CPU kernel's arithmetic), takes the running
minimum, multiplies by the clamped weight when weighted, and picks the first maximum
(``tie_break_left``), i.e. the same index as the PyTorch loop's ``argmax``. Padding slots hold a
running distance of -1 and never win. The number of picks is a compile-time constant (Triton's
interpreter, which the CPU-only tests use, cannot loop to a run-time bound): a model's few sampling
sizes compile once each, and Triton caches the builds on disk.

Triton is optional: it comes with PyTorch's CUDA builds and is absent from the CPU build, so this
module imports without it (:data:`AVAILABLE` is then False) and the callers keep the PyTorch loop.
Tested against the PyTorch loop on a GPU (``tests/test_sasa_cuda.py``) and, where Triton is installed
without a GPU, in Triton's interpreter.
"""

from __future__ import annotations

import math

import torch

try:  # Triton ships with PyTorch's CUDA builds only
    import triton
    import triton.language as tl
except ImportError:  # the CPU build of PyTorch
    triton = None
    tl = None

__all__ = ["AVAILABLE", "MAX_POINTS", "fps_triton", "usable"]

#: Whether Triton could be imported.
AVAILABLE = triton is not None
#: Largest cloud one program holds in registers: the study preset's 16384 input points, the largest
#: size tested on a GPU (larger clouds take the PyTorch loop).
MAX_POINTS = 1 << 14


if AVAILABLE:

    @triton.jit
    def _fps_kernel(x_ptr, y_ptr, z_ptr, w_ptr, first_ptr, out_ptr, n,
                    N_ITER: tl.constexpr, WEIGHTED: tl.constexpr, BLOCK: tl.constexpr):
        b = tl.program_id(0)
        offs = tl.arange(0, BLOCK)
        inside = offs < n
        base = b.to(tl.int64) * n
        x = tl.load(x_ptr + base + offs, mask=inside, other=0.0)
        y = tl.load(y_ptr + base + offs, mask=inside, other=0.0)
        z = tl.load(z_ptr + base + offs, mask=inside, other=0.0)
        temp = tl.where(inside, 1e10, -1.0).to(x.dtype)  # the reference's temp.fill_(1e10); -1: padding
        if WEIGHTED:
            w = tl.load(w_ptr + base + offs, mask=inside, other=1.0)
        old = tl.load(first_ptr + b).to(tl.int32)
        out = out_ptr + b.to(tl.int64) * N_ITER
        tl.store(out, old)
        for j in tl.range(1, N_ITER):
            px = tl.load(x_ptr + base + old)
            py = tl.load(y_ptr + base + old)
            pz = tl.load(z_ptr + base + old)
            dx = x - px
            d = dx * dx
            dy = y - py
            d = d + dy * dy
            dz = z - pz
            d = d + dz * dz
            temp = tl.minimum(temp, d)
            if WEIGHTED:
                score = temp * w
            else:
                score = temp
            old = tl.argmax(score, axis=0, tie_break_left=True).to(tl.int32)
            tl.store(out + j, old)


def usable(xp: torch.Tensor, wp: torch.Tensor | None) -> bool:
    """Whether :func:`fps_triton` applies: Triton present, a CUDA tensor of float32/float64, at most
    ``MAX_POINTS`` points (at least one cloud of at least one point), finite coordinates and weights."""
    if not AVAILABLE or xp.device.type != "cuda" or xp.dtype not in (torch.float32, torch.float64):
        return False
    if xp.shape[0] == 0 or not 1 <= xp.shape[1] <= MAX_POINTS:
        return False
    return bool(torch.isfinite(xp).all()) and (wp is None or bool(torch.isfinite(wp).all()))


def fps_triton(xp: torch.Tensor, w_clamped: torch.Tensor | None, first: torch.Tensor, n_iter: int) -> torch.Tensor:
    """Preference positions (B, n_iter) int64 picked by FPS on the GPU.

    Args:
        xp: (B, N, 3) coordinates in preference order (float32/float64, CUDA, finite), N <= MAX_POINTS.
        w_clamped: (B, N) weights already clamped to the reference's minimum (same dtype), or None
            for D-FPS.
        first: (B,) the first pick of each cloud (position in preference order).
        n_iter: number of picks, 1 <= n_iter <= N.
    """
    B, N, _ = xp.shape
    x, y, z = (xp[..., i].contiguous() for i in range(3))
    w = x if w_clamped is None else w_clamped.to(xp.dtype).contiguous()
    out = torch.empty((B, n_iter), dtype=torch.long, device=xp.device)
    block = max(16, 1 << math.ceil(math.log2(N)))
    warps = min(32, max(4, block // 512))  # 16-32 points of each array per thread
    _fps_kernel[(B,)](x, y, z, w, first.to(torch.int32).contiguous(), out, N, N_ITER=n_iter,
                      WEIGHTED=w_clamped is not None, BLOCK=block, num_warps=warps, enable_fp_fusion=False)
    return out
