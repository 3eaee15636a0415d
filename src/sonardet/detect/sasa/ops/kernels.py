"""Compiled CPU kernels (Numba) for furthest point sampling and the ball query.

They compute exactly what the pure-PyTorch operators of :mod:`.sampling` and :mod:`.grouping` compute
(same indices, same float arithmetic: every distance is ``(x - x1)^2 + (y - y1)^2 + (z - z1)^2`` in
the dtype of the coordinates, one rounding per operation, no fused multiply-add), with far less work:

* **FPS** (:func:`fps_kernel`): the points (already in the reference kernel's tie-break preference
  order, see :mod:`.sampling`) are grouped into spatial blocks of ``FPS_BLOCK`` points (Morton order of
  a coarse grid). Each block keeps its bounding box, the largest running distance of its points and
  its best score (largest ``temp * w``, ties to the smallest preference position). After a pick, a
  block whose bounding box is farther from the picked point than its largest running distance (with a
  relative margin far above the rounding error) cannot change and is skipped; the next pick is the
  best of the block bests. Same result as a full scan, at a fraction of the work late in the sampling.
  The skip test runs over all blocks without branches, and the minima and maxima of the running
  distances and scores are taken on their bit patterns read as integers (non-negative floats order
  alike), so that both loops run in vector lanes: the same picks, 2-3x faster than the same blocks
  scanned with branches (docs/speed_log.md, "FPS in vector lanes").
* **Ball query** (:func:`ball_query_kernel`): points are binned into vertical columns of a 2-D grid
  whose cells are at least the largest radius (with a rounding margin); a query tests only the points
  of its 3 x 3 columns (three contiguous runs of the points in column order), marks its hits in a
  bitmap over the point indices and reads them out in index order (no sort), keeping the first
  ``nsample`` of every shell.

* **Weighted batch norm + ReLU** (:func:`weighted_bn_relu_forward` / ``_backward``): the compact
  grouped MLP's normalisation fused into two passes forward and two backward (float64 statistics),
  over row chunks (four per torch thread) that run in parallel on arrays of at least
  ``PARALLEL_MIN_ELEMENTS`` values and one after the other below (the same numbers either way).
* **Segment max** (:func:`segment_max_forward` / ``_backward``): the max over each centre's
  contiguous rows (``torch.segment_reduce(..., "max")``) and its gradient with PyTorch's CPU
  semantics (NaN wins; the gradient goes to every row equal to the max, and where two or more tie,
  the positive ones are divided by their count), row-major and parallel over segments; PyTorch's
  backward walks each channel down the rows, a strided pass per channel.
* **The last layer and the max together** (:func:`bn_relu_segment_max_forward` / ``_backward``): a
  grouped MLP's last batch norm + ReLU followed by the segment max, on the calling thread, without
  the (R, C) output and gradient between them: the forward keeps only the max and each max's tie
  count, the backward makes each row's gradient from its segment's where it is used. The same bits
  as the two pairs of kernels above (`tests/test_sasa_speed.py`), about a quarter to a third faster.

The batch-norm kernels need finite rows: a non-finite one makes its channel's statistics non-finite,
which the callers (`backbone._check_finite_stats`) turn into a FloatingPointError before using the
output (the segment max alone follows PyTorch's NaN rule above). Compiled on first use
and cached on disk (``cache=True``); FPS and the ball query run one thread per cloud of the batch.
"""

from __future__ import annotations

import math

import numpy as np

from numba import types
from numba.extending import overload

from ....jit import numba  # the fork-safe threading layer (see sonardet.jit)

__all__ = ["FPS_BLOCK", "fps_kernel", "ball_query_kernel", "grid_cell", "weighted_bn_relu_forward",
           "weighted_bn_relu_backward", "segment_max_forward", "segment_max_backward", "bn_relu_segment_max_forward",
           "bn_relu_segment_max_backward", "parallel_chunks",
           "run_parallel", "PARALLEL_MIN_ELEMENTS"]

#: Points per FPS block (bounding-box test granularity).
FPS_BLOCK = 64
#: Relative margin of the block skip test: a block is skipped only if its box is farther than
#: ``maxtemp / (1 - margin)``; float rounding of a squared distance is below 1e-6 relative.
_SKIP_MARGIN = 1e-5
#: Initial running distance of the reference kernel (``temp.fill_(1e10)``).
_TEMP_INIT = 1e10

_JIT = dict(cache=True, nogil=True)
_JIT_PAR = dict(cache=True, nogil=True, parallel=True)


@numba.njit(**_JIT)
def _morton_order(x, y, z):
    """Permutation grouping the points (N,) of a cloud spatially (Morton order of a 1024^3 grid)."""
    n = x.shape[0]
    lo = np.empty(3)
    span = np.empty(3)
    for a, v in enumerate((x, y, z)):
        lo[a] = v.min()
        span[a] = max(v.max() - lo[a], 1e-30)
    code = np.empty(n, np.int64)
    for i in range(n):
        c = 0
        qs = (int((x[i] - lo[0]) / span[0] * 1023.0), int((y[i] - lo[1]) / span[1] * 1023.0),
              int((z[i] - lo[2]) / span[2] * 1023.0))
        for bit in range(10):
            for a in range(3):
                c |= ((qs[a] >> bit) & 1) << (3 * bit + a)
        code[i] = c
    return np.argsort(code, kind="mergesort")


@numba.njit(**_JIT)
def _block_bounds(px, py, pz, nblk, bs):
    """Bounding boxes of consecutive blocks, one float64 array (nblk,) per bound: xmin, ymin, zmin,
    xmax, ymax, zmax (one array each, so that the skip test runs over the blocks in vector lanes)."""
    n = px.shape[0]
    box = np.empty((6, nblk))
    for k in range(nblk):
        s, e = k * bs, min(n, (k + 1) * bs)
        box[0, k], box[1, k], box[2, k] = px[s:e].min(), py[s:e].min(), pz[s:e].min()
        box[3, k], box[4, k], box[5, k] = px[s:e].max(), py[s:e].max(), pz[s:e].max()
    return box


def _bits(a):
    """The array `a` (float32 / float64) viewed as signed integers of its width (float32 -> int32,
    float64 -> int64)."""
    raise NotImplementedError("compiled use only")  # pragma: no cover


@overload(_bits)
def _bits_impl(a):
    width = {types.float32: np.int32, types.float64: np.int64}.get(a.dtype)
    if width is None:
        return None
    return lambda a: a.view(width)


@numba.njit(**_JIT)
def _near_blocks(box, qx, qy, qz, maxtemp, near_flag, near):
    """The blocks that the pick (qx, qy, qz) may change, ascending, into `near`; returns their count.

    A block is skipped when the squared distance (float64) from the pick to its bounding box, shrunk
    by the relative margin, is at least its largest running distance. The distance is the per-axis
    gap (max(lo - q, 0) + max(q - hi, 0): the one non-zero term, or 0 inside) squared and summed in
    axis order, the same float64 value as summing the gaps of the outside axes alone (adding 0.0
    changes nothing); branch-free, so the scan over the blocks runs in vector lanes."""
    qx, qy, qz = np.float64(qx), np.float64(qy), np.float64(qz)
    nblk = maxtemp.shape[0]
    for k in range(nblk):
        gx = max(box[0, k] - qx, 0.0) + max(qx - box[3, k], 0.0)
        gy = max(box[1, k] - qy, 0.0) + max(qy - box[4, k], 0.0)
        gz = max(box[2, k] - qz, 0.0) + max(qz - box[5, k], 0.0)
        d2 = gx * gx
        d2 = d2 + gy * gy
        d2 = d2 + gz * gz
        near_flag[k] = d2 * (1.0 - _SKIP_MARGIN) < np.float64(maxtemp[k])
    m = 0
    for k in range(nblk):
        if near_flag[k]:
            near[m] = k
            m += 1
    return m


@numba.njit(**_JIT)
def _update_block(k, bs, px, py, pz, pw, pos, temp_bits, qx, qy, qz, buf, blk_maxtemp_bits, blk_score_bits, blk_pos,
                  weighted):
    """Update the running distances of block k after picking (qx, qy, qz); refresh its largest running
    distance and its best (largest score, ties to the smallest preference position).

    Running distances and scores are non-negative finite floats, which order as their bit patterns
    read as signed integers: the minima and maxima are taken on those integers (`temp_bits`, the
    `*_bits` arrays: integer views of the float arrays), the same values as the float comparisons,
    in vector lanes (LLVM does not vectorise a float min/max reduction without fast-math). The
    caller makes the views once per cloud: made here, on every call, they slowed D-FPS 8192 -> 2048
    by 10-25 % (`benchmarks/sasa_ops.py --sampling-only`)."""
    n = px.shape[0]
    s, e = k * bs, min(n, (k + 1) * bs)
    ax, ay, az = px[s:e], py[s:e], pz[s:e]
    d = buf[: e - s]
    for i in range(ax.shape[0]):
        # Same operation order as the reference kernel: d = dx*dx + dy*dy + dz*dz, one rounding each.
        dx = ax[i] - qx
        dy = ay[i] - qy
        dz = az[i] - qz
        v = dx * dx
        v = v + dy * dy
        d[i] = v + dz * dz
    dbits, tbits = _bits(d), temp_bits[s:e]
    mt = tbits.dtype.type(-1)
    for i in range(tbits.shape[0]):
        t = min(dbits[i], tbits[i])
        tbits[i] = t
        mt = max(mt, t)
    blk_maxtemp_bits[k] = mt
    best = mt  # D-FPS: the score is the running distance
    if weighted:
        temp, w = temp_bits[s:e].view(d.dtype), pw[s:e]
        for i in range(temp.shape[0]):
            d[i] = temp[i] * w[i]
        best = tbits.dtype.type(-1)
        for i in range(dbits.shape[0]):
            best = max(best, dbits[i])
    else:
        dbits = tbits
    p, bpos = pos[s:e], n
    for i in range(dbits.shape[0]):
        if dbits[i] == best:
            bpos = min(bpos, p[i])
    blk_score_bits[k] = best
    blk_pos[k] = bpos


@numba.njit(**_JIT)
def _best_of_blocks(score_bits, blk_pos, n):
    """Preference position of the best point: the largest block score (integer view of non-negative
    floats, see `_update_block`), ties to the smallest position."""
    best = score_bits[0]
    for k in range(1, score_bits.shape[0]):
        best = max(best, score_bits[k])
    bpos = n
    for k in range(score_bits.shape[0]):
        if score_bits[k] == best:
            bpos = min(bpos, blk_pos[k])
    return bpos


@numba.njit(**_JIT)
def _fps_one(xyz, w, n_iter, first, out, weighted):
    """Block FPS of one cloud xyz (N, 3) in preference order; w (N,) clamped weights (ignored unless
    `weighted`); out (n_iter,)."""
    n = xyz.shape[0]
    bs = FPS_BLOCK
    order = _morton_order(xyz[:, 0], xyz[:, 1], xyz[:, 2])
    px, py, pz = xyz[order, 0].copy(), xyz[order, 1].copy(), xyz[order, 2].copy()
    pw = w[order].copy()
    pos = order.astype(np.int64)
    where = np.empty(n, np.int64)  # preference position -> slot in block order
    where[pos] = np.arange(n)
    nblk = (n + bs - 1) // bs
    box = _block_bounds(px, py, pz, nblk, bs)
    temp = np.full(n, _TEMP_INIT, xyz.dtype)
    blk_maxtemp = np.full(nblk, _TEMP_INIT, xyz.dtype)
    blk_score = np.zeros(nblk, xyz.dtype)
    temp_bits, maxtemp_bits, score_bits = _bits(temp), _bits(blk_maxtemp), _bits(blk_score)
    blk_pos = np.zeros(nblk, np.int64)
    buf = np.empty(bs, xyz.dtype)
    near_flag = np.empty(nblk, np.bool_)
    near = np.empty(nblk, np.int64)
    old = first
    out[0] = old
    for j in range(1, n_iter):
        s = where[old]
        qx, qy, qz = px[s], py[s], pz[s]
        m = _near_blocks(box, qx, qy, qz, blk_maxtemp, near_flag, near)
        for t in range(m):
            _update_block(near[t], bs, px, py, pz, pw, pos, temp_bits, qx, qy, qz, buf, maxtemp_bits, score_bits,
                          blk_pos, weighted)
        old = _best_of_blocks(score_bits, blk_pos, n)
        out[j] = old


@numba.njit(**_JIT_PAR)
def fps_kernel(xyz, w_raw, w_clamped, n_iter, weighted):
    """Furthest point sampling of a batch, in preference positions.

    Args:
        xyz: (B, N, 3) float32/float64 C-contiguous finite coordinates, already permuted into the
            reference kernel's preference order (position 0 = original index 0).
        w_raw: (B, N) raw weights in the same order (the first pick of weighted FPS).
        w_clamped: (B, N) weights clamped to >= 1e-12, same dtype as xyz (the score factor).
        n_iter: samples per cloud, 1 <= n_iter <= N.
        weighted: False: D-FPS (start at position 0, score = running squared distance, weights
            ignored); True: weighted FPS (start at the first largest raw weight, score = running
            distance times the clamped weight).

    Returns:
        (B, n_iter) int64 positions in the preference order (map back with the order permutation).

    The clouds of the batch are sampled in parallel (Numba's thread count, see :func:`parallel_chunks`),
    each by one thread as before: the same picks.
    """
    B, n = xyz.shape[0], xyz.shape[1]
    out = np.empty((B, n_iter), np.int64)
    ones = np.ones(n, xyz.dtype)
    for b in numba.prange(B):
        first = 0
        if weighted:
            for i in range(1, n):
                if w_raw[b, i] > w_raw[b, first]:
                    first = i
            _fps_one(xyz[b], w_clamped[b], n_iter, first, out[b], True)
        else:
            _fps_one(xyz[b], ones, n_iter, first, out[b], False)
    return out


@numba.njit(**_JIT)
def _column_grid(x, y, cell):
    """Points binned into 2-D columns of size ``cell``: (start (nc + 1,), members sorted by index,
    x0, y0, nx, ny)."""
    n = x.shape[0]
    x0, y0 = np.float64(x.min()), np.float64(y.min())
    nx = int((np.float64(x.max()) - x0) / cell) + 1
    ny = int((np.float64(y.max()) - y0) / cell) + 1
    key = np.empty(n, np.int64)
    for i in range(n):
        key[i] = int((np.float64(x[i]) - x0) / cell) * ny + int((np.float64(y[i]) - y0) / cell)
    start = np.zeros(nx * ny + 1, np.int64)
    for i in range(n):
        start[key[i] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    members = np.empty(n, np.int64)
    for i in range(n):  # counting sort: ascending point index within every column
        members[fill[key[i]]] = i
        fill[key[i]] += 1
    return start, members, x0, y0, nx, ny


@numba.njit(inline="always")
def _dist2(x, y, z, i, qx, qy, qz):
    """Squared distance of point i to the query, one rounding per operation in a fixed order (as the
    PyTorch reference sums it), so the ball query's shells match it bit for bit."""
    dx = qx - x[i]
    dy = qy - y[i]
    dz = qz - z[i]
    d2 = dx * dx
    d2 = d2 + dy * dy
    return d2 + dz * dz


#: De Bruijn multiplier and table of the lowest set bit's position in a 64-bit word (`_lowest_bit`).
_DEBRUIJN64 = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN64_POS = np.zeros(64, np.int64)
for _k in range(64):
    _DEBRUIJN64_POS[((1 << _k) * 0x03F79D71B4CB0A89 % (1 << 64)) >> 58] = _k


@numba.njit(inline="always")
def _lowest_bit(word):
    """Position (0-63) of the lowest set bit of a non-zero uint64 word, and the word without it."""
    low = word & (~word + np.uint64(1))
    return _DEBRUIJN64_POS[(low * _DEBRUIJN64) >> np.uint64(58)], word ^ low


@numba.njit(**_JIT)
def _mark_hits(xs, ys, zs, start, members, x0, y0, nx, ny, cell, qx, qy, qz, rmax2, d2_of, words):
    """Mark the points with d^2 < rmax2 in the 3 x 3 columns around a query: bit (i & 63) of word
    i >> 6 of `words` set, d2_of[i] = d^2. Returns the range (lo, hi) of words touched (lo > hi: none).

    xs, ys, zs: the coordinates in column order (``x[members]``...): the columns of one grid row are
    one contiguous run, three runs per query (the same distances: same coordinates, same operations).
    The bitmap hands the hits out in index order with no sort (`_assign_shells`)."""
    ix = math.floor((np.float64(qx) - x0) / cell)
    iy = math.floor((np.float64(qy) - y0) / cell)
    lo, hi = words.shape[0], -1
    cy0, cy1 = max(iy - 1, 0), min(iy + 1, ny - 1)
    if cy0 > cy1:
        return lo, hi
    for cx in range(max(ix - 1, 0), min(ix + 1, nx - 1) + 1):
        for t in range(start[cx * ny + cy0], start[cx * ny + cy1 + 1]):
            # Branch-free: a miss writes its distance where no marked bit reads it, and sets no bit.
            d2 = _dist2(xs, ys, zs, t, qx, qy, qz)
            hit = np.uint64(d2 < rmax2)
            i = members[t]
            d2_of[i] = d2
            w = i >> 6
            words[w] |= hit << np.uint64(i & 63)
            lo = min(lo, w if hit else lo)
            hi = max(hi, w if hit else hi)
    return lo, hi


@numba.njit(**_JIT)
def _assign_shells(words, lo, hi, d2_of, r_in2, r_out2, nsamples, offsets, out, cnt):
    """First nsample hits (index order: the set bits of `words[lo:hi + 1]`, read and cleared) of every
    shell; cyclic padding. `cnt` (S,) must be zero on entry: it counts the hits kept."""
    S = r_out2.shape[0]
    full = 0
    for w in range(lo, hi + 1):
        word = words[w]
        words[w] = 0
        while word != 0 and full < S:
            b, word = _lowest_bit(word)
            i = (w << 6) + b
            d2 = d2_of[i]
            for s in range(S):
                if cnt[s] < nsamples[s] and d2 >= r_in2[s] and d2 < r_out2[s]:
                    out[offsets[s] + cnt[s]] = i
                    cnt[s] += 1
                    if cnt[s] == nsamples[s]:
                        full += 1
    for s in range(S):
        c = cnt[s]
        if c > 0:
            for j in range(c, nsamples[s]):
                out[offsets[s] + j] = out[offsets[s] + j % c]


@numba.njit(**_JIT_PAR)
def ball_query_kernel(xyz, new_xyz, r_in2, r_out2, nsamples, cell):
    """Multi-shell ball query of a batch (the reference semantics of :mod:`.grouping`).

    Args:
        xyz: (B, N, 3) finite point coordinates; new_xyz: (B, M, 3) finite centres, same dtype.
        r_in2: (S,) squared inner radii in that dtype (-inf: a ball, no inner bound), inclusive.
        r_out2: (S,) squared outer radii in that dtype, exclusive.
        nsamples: (S,) int64 neighbours kept per shell.
        cell: column size (m, float64), at least the largest outer radius plus a rounding margin
            (see :func:`grid_cell`).

    Returns:
        (idx (B, M, sum(nsamples)) int64, the shells' index blocks side by side; cnt (B, M, S) int64
        hits kept per shell). Empty shells keep count 0 and indices 0.

    The clouds of the batch are queried in parallel (Numba's thread count), each by one thread.
    """
    B, N, M, S = xyz.shape[0], xyz.shape[1], new_xyz.shape[1], r_out2.shape[0]
    offsets = np.zeros(S, np.int64)
    for s in range(1, S):
        offsets[s] = offsets[s - 1] + nsamples[s - 1]
    out = np.zeros((B, M, offsets[S - 1] + nsamples[S - 1]), np.int64)
    cnt = np.zeros((B, M, S), np.int64)
    rmax2 = r_out2.max()
    for b in numba.prange(B):
        x, y, z = xyz[b, :, 0].copy(), xyz[b, :, 1].copy(), xyz[b, :, 2].copy()
        start, members, x0, y0, nx, ny = _column_grid(x, y, cell)
        xs, ys, zs = x[members], y[members], z[members]
        d2_of = np.empty(N, xyz.dtype)
        words = np.zeros((N + 63) // 64, np.uint64)
        for m in range(M):
            qx, qy, qz = new_xyz[b, m, 0], new_xyz[b, m, 1], new_xyz[b, m, 2]
            lo, hi = _mark_hits(xs, ys, zs, start, members, x0, y0, nx, ny, cell, qx, qy, qz, rmax2, d2_of, words)
            _assign_shells(words, lo, hi, d2_of, r_in2, r_out2, nsamples, offsets, out[b, m], cnt[b, m])
    return out, cnt


def grid_cell(r_max: float, scale: float, n_points: int, extent: float) -> float:
    """Column size (m) for :func:`ball_query_kernel`: the largest radius ``r_max`` (m) grown by the
    rounding margin of the tiled PyTorch query (``1e-3`` relative plus ``1e-5 (1 + scale)``, ``scale``
    the largest absolute coordinate), and at least ``extent / sqrt(4 n_points)`` so that a sparse
    cloud over a large extent never needs more than ~4 columns per point."""
    cell = r_max * (1.0 + 1e-3) + 1e-5 * (1.0 + scale)
    return max(cell, extent / math.sqrt(4.0 * max(n_points, 1)))


@numba.njit(**_JIT)
def _weighted_sums_rows(h, wn, centre, s1, s2, lo, hi):
    """Adds the weighted sums of (h - centre) and (h - centre)^2 over rows lo:hi into s1, s2 (C,)."""
    C = h.shape[1]
    for i in range(lo, hi):
        w = np.float64(wn[i])
        for c in range(C):
            d = np.float64(h[i, c]) - centre[c]
            s1[c] += w * d
            s2[c] += w * d * d


@numba.njit(**_JIT_PAR)
def _weighted_sums_parallel(h, wn, centre, s1, s2):
    R, n = h.shape[0], s1.shape[0]
    for k in numba.prange(n):
        _weighted_sums_rows(h, wn, centre, s1[k], s2[k], k * R // n, (k + 1) * R // n)


@numba.njit(**_JIT)
def _weighted_sums(h, wn, centre, nchunks, parallel):
    """Per-chunk weighted column sums of (h - centre) and (h - centre)^2 (float64, (nchunks, C) each)."""
    R, C = h.shape
    s1 = np.zeros((nchunks, C))
    s2 = np.zeros((nchunks, C))
    if parallel:
        _weighted_sums_parallel(h, wn, centre, s1, s2)
    else:
        for k in range(nchunks):
            _weighted_sums_rows(h, wn, centre, s1[k], s2[k], k * R // nchunks, (k + 1) * R // nchunks)
    return s1, s2


#: Rows (evenly strided) whose weighted mean centres the batch-norm sums of `weighted_bn_relu_forward`.
PROVISIONAL_MEAN_ROWS = 1024


@numba.njit(cache=True, nogil=True)
def _provisional_mean(h, wn):
    """Weighted column mean (C,) float64 of at most PROVISIONAL_MEAN_ROWS evenly strided rows of h (R, C)
    (the plain mean of those rows if their weights sum to 0; zeros for R = 0)."""
    R, C = h.shape
    step = max(1, R // PROVISIONAL_MEAN_ROWS)
    acc = np.zeros(C)
    plain = np.zeros(C)
    wsum = 0.0
    n = 0
    for i in range(0, R, step):
        w = np.float64(wn[i])
        wsum += w
        n += 1
        for c in range(C):
            acc[c] += w * np.float64(h[i, c])
            plain[c] += np.float64(h[i, c])
    if wsum > 0:
        return acc / wsum
    return plain / max(n, 1)


@numba.njit(cache=True, nogil=True)
def _bn_affine(mean, var, gamma, beta, eps):
    """The float32 scale and offset (C,) of the normalised, affine output ``h * scale + offset`` (the
    forward's, and the backward's recomputation of its ReLU mask: one function, so the same bits)."""
    inv = gamma.astype(np.float64) / np.sqrt(var + eps)
    return inv.astype(np.float32), (beta.astype(np.float64) - mean * inv).astype(np.float32)


@numba.njit(**_JIT)
def _weighted_stats(h, wn, nchunks, parallel):
    """The weighted mean and biased variance (C,) float64 of rows h (R, C) (see
    `weighted_bn_relu_forward`): centred float64 sums around a provisional mean, per chunk."""
    mean0 = _provisional_mean(h, wn)
    s1, s2 = _weighted_sums(h, wn, mean0, nchunks, parallel)
    # Divided by the weights' own float64 sum (1 up to float32 rounding), so the result does not
    # depend on the provisional mean.
    wsum = wn.astype(np.float64).sum()
    wsum = wsum if wsum > 0 else 1.0
    shift = s1.sum(axis=0) / wsum
    mean = mean0 + shift
    var = np.maximum(s2.sum(axis=0) / wsum - shift * shift, 0.0)
    return mean, var


@numba.njit(**_JIT)
def _bn_relu_rows(h, scale, offset, y, lo, hi):
    C = h.shape[1]
    for i in range(lo, hi):
        for c in range(C):
            v = h[i, c] * scale[c] + offset[c]
            y[i, c] = v if v > 0 else np.float32(0.0)


@numba.njit(**_JIT_PAR)
def _bn_relu_parallel(h, scale, offset, y, nchunks):
    R = h.shape[0]
    for k in numba.prange(nchunks):
        _bn_relu_rows(h, scale, offset, y, k * R // nchunks, (k + 1) * R // nchunks)


@numba.njit(**_JIT)
def weighted_bn_relu_forward(h, wn, gamma, beta, eps, nchunks, parallel=True):
    """Fused weighted batch norm + ReLU over rows h (R, C) float32 with row weights wn (R,) summing to 1.

    Returns (y (R, C) float32, mean (C,) float64, biased variance (C,) float64). The statistics are
    accumulated in float64 around a provisional mean (the weighted mean of at most
    `PROVISIONAL_MEAN_ROWS` evenly strided rows: any value near the mean keeps the centred sums from
    cancelling, and a sample costs a fraction of a pass over all rows), then corrected by the centred
    sums' own mean: one pass over h for the statistics, one for the output. The rows are cut into
    ``nchunks`` chunks, which fix the order of the sums; ``parallel`` runs the chunks on Numba's
    threads, else one after the other on the calling thread (the same numbers either way).
    """
    R = h.shape[0]
    mean, var = _weighted_stats(h, wn, nchunks, parallel)
    scale, offset = _bn_affine(mean, var, gamma, beta, eps)
    y = np.empty_like(h)
    if parallel:
        _bn_relu_parallel(h, scale, offset, y, nchunks)
    else:
        _bn_relu_rows(h, scale, offset, y, 0, R)
    return y, mean, var


@numba.njit(**_JIT)
def _bn_grad_sums_rows(gy, h, scale, offset, mean32, inv32, sb, sg, lo, hi):
    C = h.shape[1]
    for i in range(lo, hi):
        for c in range(C):
            # Branch-free (adds 0 where the ReLU is off: the same sums), so the loop vectorises; gy is
            # read whatever the mask (a read under the condition becomes a masked or scalar load).
            x = h[i, c]
            gv = np.float64(gy[i, c])
            g = gv if x * scale[c] + offset[c] > 0 else 0.0
            sb[c] += g
            sg[c] += g * np.float64((x - mean32[c]) * inv32[c])


@numba.njit(**_JIT)
def _bn_grad_rows(gy, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, lo, hi):
    C = h.shape[1]
    for i in range(lo, hi):
        w = wn[i]
        for c in range(C):
            x = h[i, c]
            gv = gy[i, c]  # read whatever the mask, as in _bn_grad_sums_rows
            g = gv if x * scale[c] + offset[c] > 0 else np.float32(0.0)
            xhat = (x - mean32[c]) * inv32[c]
            dh[i, c] = a[c] * (g - w * (db32[c] + xhat * dg32[c]))


@numba.njit(**_JIT_PAR)
def _bn_grad_sums_parallel(gy, h, scale, offset, mean32, inv32, sb, sg):
    R, n = h.shape[0], sb.shape[0]
    for k in numba.prange(n):
        _bn_grad_sums_rows(gy, h, scale, offset, mean32, inv32, sb[k], sg[k], k * R // n, (k + 1) * R // n)


@numba.njit(**_JIT_PAR)
def _bn_grad_parallel(gy, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, nchunks):
    R = h.shape[0]
    for k in numba.prange(nchunks):
        _bn_grad_rows(gy, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, k * R // nchunks,
                      (k + 1) * R // nchunks)


@numba.njit(**_JIT)
def _grad_setup(mean, var, invstd, gamma, beta, eps, nchunks, C):
    """What a batch-norm backward pass needs first: the forward's float32 scale and offset (its ReLU
    mask), zeroed float64 per-chunk sums (nchunks, C) of the gradient and of its product with xhat,
    and the float32 mean and inverse standard deviation."""
    scale, offset = _bn_affine(mean, var, gamma, beta, eps)
    return (scale, offset, np.zeros((nchunks, C)), np.zeros((nchunks, C)), mean.astype(np.float32),
            invstd.astype(np.float32))


@numba.njit(**_JIT)
def _grad_coefficients(sb, sg, gamma, invstd):
    """From the per-chunk sums: dbeta, dgamma (C,) float64 and the float32 coefficients of dh
    (gamma invstd, dbeta, dgamma)."""
    dbeta = sb.sum(axis=0)
    dgamma = sg.sum(axis=0)
    a = (gamma.astype(np.float64) * invstd).astype(np.float32)
    return dbeta, dgamma, a, dbeta.astype(np.float32), dgamma.astype(np.float32)


@numba.njit(**_JIT)
def weighted_bn_relu_backward(gy, h, wn, mean, var, invstd, gamma, beta, eps, nchunks, parallel=True):
    """Gradient of :func:`weighted_bn_relu_forward`: (dh (R, C) float32, dgamma (C,), dbeta (C,)).

    ``dh_i = gamma invstd (G_i - wn_i (sum G + xhat_i sum G xhat))`` with ``G = gy [y > 0]`` and
    ``xhat = (h - mean) invstd``: the batch-norm gradient of the population the rows stand for.
    The ReLU's mask ``y > 0`` is recomputed from h with the forward's own float32 scale and offset
    (the same operations, so the same mask bit for bit) instead of read from y: the two passes are
    bound by memory bandwidth, and this reads two arrays of (R, C) in each instead of three.
    ``nchunks`` and ``parallel`` as in the forward.
    """
    R, C = h.shape
    scale, offset, sb, sg, mean32, inv32 = _grad_setup(mean, var, invstd, gamma, beta, eps, nchunks, C)
    if parallel:
        _bn_grad_sums_parallel(gy, h, scale, offset, mean32, inv32, sb, sg)
    else:
        for k in range(nchunks):
            _bn_grad_sums_rows(gy, h, scale, offset, mean32, inv32, sb[k], sg[k], k * R // nchunks,
                               (k + 1) * R // nchunks)
    dbeta, dgamma, a, db32, dg32 = _grad_coefficients(sb, sg, gamma, invstd)
    dh = np.empty_like(h)
    if parallel:
        _bn_grad_parallel(gy, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, nchunks)
    else:
        _bn_grad_rows(gy, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, 0, R)
    return dh, dgamma, dbeta


@numba.njit(**_JIT)
def _segment_max_rows(h, offsets, out, lo, hi):
    C = h.shape[1]
    for s in range(lo, hi):
        a = offsets[s]
        for c in range(C):
            out[s, c] = h[a, c]
        for i in range(a + 1, offsets[s + 1]):
            for c in range(C):
                v = h[i, c]
                m = out[s, c]
                out[s, c] = v if (np.isnan(v) or m < v) else m


@numba.njit(**_JIT_PAR)
def _segment_max_parallel(h, offsets, out, nchunks):
    S = offsets.shape[0] - 1
    for k in numba.prange(nchunks):
        _segment_max_rows(h, offsets, out, k * S // nchunks, (k + 1) * S // nchunks)


@numba.njit(**_JIT)
def segment_max_forward(h, offsets, nchunks, parallel=True):
    """Max over contiguous row segments: rows offsets[s]:offsets[s + 1] of h (R, C) -> (S, C), S =
    len(offsets) - 1, every segment non-empty. A NaN row value makes its channel's max NaN (PyTorch's rule).
    ``parallel``: segment chunks on Numba's threads, else on the calling thread."""
    S = offsets.shape[0] - 1
    C = h.shape[1]
    out = np.empty((S, C), dtype=h.dtype)
    if parallel:
        _segment_max_parallel(h, offsets, out, nchunks)
    else:
        _segment_max_rows(h, offsets, out, 0, S)
    return out


@numba.njit(**_JIT)
def _segment_max_grad_rows(g, out, h, offsets, gi, lo, hi):
    C = h.shape[1]
    zero = np.float32(0.0)
    cnt = np.zeros(C, dtype=np.int64)
    for s in range(lo, hi):
        a, b = offsets[s], offsets[s + 1]
        cnt[:] = 0
        for i in range(a, b):
            for c in range(C):  # branch-free, so that the loop vectorises; every element written
                v = h[i, c]
                gv = g[s, c]  # read whatever the test (as in _bn_grad_sums_rows)
                hit = np.isnan(v) or v == out[s, c]
                gi[i, c] = gv if hit else zero
                cnt[c] += hit
        if cnt.max() >= 2:  # ties in some channel
            for i in range(a, b):
                for c in range(C):
                    if cnt[c] >= 2 and gi[i, c] > 0:
                        gi[i, c] = gi[i, c] / np.float32(cnt[c])


@numba.njit(**_JIT_PAR)
def _segment_max_grad_parallel(g, out, h, offsets, gi, nchunks):
    S = offsets.shape[0] - 1
    for k in numba.prange(nchunks):
        _segment_max_grad_rows(g, out, h, offsets, gi, k * S // nchunks, (k + 1) * S // nchunks)


@numba.njit(**_JIT)
def segment_max_backward(g, out, h, offsets, nchunks, parallel=True):
    """Gradient of :func:`segment_max_forward` for the output gradient g (S, C): PyTorch's CPU rule,
    each row whose value equals its segment's max (or is NaN) gets g; where n >= 2 rows of a channel
    do, those with a positive gradient get g / n. Returns (R, C), zero elsewhere."""
    S = offsets.shape[0] - 1
    gi = np.empty_like(h)
    if parallel:
        _segment_max_grad_parallel(g, out, h, offsets, gi, nchunks)
    else:
        _segment_max_grad_rows(g, out, h, offsets, gi, 0, S)
    return gi


@numba.njit(**_JIT)
def _bn_relu_max_rows(h, scale, offset, offsets, out, ties, lo, hi):
    """Segments lo:hi of `bn_relu_segment_max_forward`: the max of the batch-norm + ReLU output over each
    segment's rows (`_bn_relu_rows`' values, `_segment_max_rows`' order), then the rows equal to it.
    The output is never NaN (a NaN v gives 0), so `_segment_max_rows`' NaN tests are left out."""
    C = h.shape[1]
    zero = np.float32(0.0)
    for s in range(lo, hi):
        a, b = offsets[s], offsets[s + 1]
        for c in range(C):
            v = h[a, c] * scale[c] + offset[c]
            out[s, c] = v if v > 0 else zero
        for i in range(a + 1, b):
            for c in range(C):
                v = h[i, c] * scale[c] + offset[c]
                y = v if v > 0 else zero
                m = out[s, c]
                out[s, c] = y if m < y else m
        # The segment's rows again (a few kB, still in cache): how many reach the max.
        for i in range(a, b):
            for c in range(C):
                v = h[i, c] * scale[c] + offset[c]
                y = v if v > 0 else zero
                ties[s, c] += y == out[s, c]


@numba.njit(**_JIT)
def bn_relu_segment_max_forward(h, wn, gamma, beta, eps, offsets, nchunks):
    """`weighted_bn_relu_forward` followed by `segment_max_forward`, without the (R, C) output between
    them: (max (S, C) float32, ties (S, C) int32, mean (C,) float64, biased variance (C,) float64).

    ``ties[s, c]``: the rows of segment s whose output equals the max in channel c, what
    `segment_max_backward` counts. The same statistics (same chunks, same sums) and the same output
    values, bit for bit, on the calling thread; every segment non-empty. The output y is recomputed
    from h where it is needed (one multiply-add per value) instead of written and read back: the
    passes are bound by memory bandwidth."""
    C = h.shape[1]
    mean, var = _weighted_stats(h, wn, nchunks, False)
    scale, offset = _bn_affine(mean, var, gamma, beta, eps)
    S = offsets.shape[0] - 1
    out = np.empty((S, C), dtype=h.dtype)
    ties = np.zeros((S, C), dtype=np.int32)
    _bn_relu_max_rows(h, scale, offset, offsets, out, ties, 0, S)
    return out, ties, mean, var


@numba.njit(**_JIT)
def _max_grads(g, ties):
    """Per segment and channel, the gradient `segment_max_backward` gives each row at the max: g, and
    g / n where n >= 2 rows tie and g > 0 (PyTorch's CPU rule), float32 (S, C)."""
    gd = g.copy()
    S, C = g.shape
    for s in range(S):
        for c in range(C):
            if ties[s, c] >= 2 and g[s, c] > 0:
                gd[s, c] = g[s, c] / np.float32(ties[s, c])
    return gd


@numba.njit(**_JIT)
def _bn_max_grad_sums_rows(gd, out, offsets, h, scale, offset, mean32, inv32, sb, sg, lo, hi):
    """`_bn_grad_sums_rows` over rows lo:hi with the gradient after the ReLU made from the segment max's:
    a row's output v = h scale + offset, where positive (the ReLU passes it), gets its segment's `gd`
    if it equals the max, else 0 (the output is never NaN: a NaN v gives 0). Branch-free, so the loop
    over channels vectorises."""
    C = h.shape[1]
    s = np.searchsorted(offsets, lo, side="right") - 1
    for i in range(lo, hi):
        while offsets[s + 1] <= i:
            s += 1
        for c in range(C):
            x = h[i, c]
            v = x * scale[c] + offset[c]
            gr = np.float64(gd[s, c]) if (v > 0) & (v == out[s, c]) else 0.0
            sb[c] += gr
            sg[c] += gr * np.float64((x - mean32[c]) * inv32[c])


@numba.njit(**_JIT)
def _bn_max_grad_rows(gd, out, offsets, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, lo, hi):
    """`_bn_grad_rows` over rows lo:hi with the gradient after the ReLU made as in `_bn_max_grad_sums_rows`."""
    C = h.shape[1]
    zero = np.float32(0.0)
    s = np.searchsorted(offsets, lo, side="right") - 1
    for i in range(lo, hi):
        while offsets[s + 1] <= i:
            s += 1
        w = wn[i]
        for c in range(C):
            x = h[i, c]
            v = x * scale[c] + offset[c]
            gr = gd[s, c] if (v > 0) & (v == out[s, c]) else zero
            xhat = (x - mean32[c]) * inv32[c]
            dh[i, c] = a[c] * (gr - w * (db32[c] + xhat * dg32[c]))


@numba.njit(**_JIT)
def bn_relu_segment_max_backward(g, out, ties, h, wn, mean, var, invstd, gamma, beta, eps, offsets, nchunks):
    """Gradient of `bn_relu_segment_max_forward` for the max's gradient g (S, C): (dh (R, C) float32,
    dgamma (C,), dbeta (C,)), bit for bit what `segment_max_backward` followed by
    `weighted_bn_relu_backward` (on the calling thread, the same chunks) give, without the (R, C)
    gradient between them: each row's gradient after the ReLU is made where it is used."""
    R, C = h.shape
    scale, offset, sb, sg, mean32, inv32 = _grad_setup(mean, var, invstd, gamma, beta, eps, nchunks, C)
    gd = _max_grads(g, ties)
    for k in range(nchunks):
        _bn_max_grad_sums_rows(gd, out, offsets, h, scale, offset, mean32, inv32, sb[k], sg[k],
                               k * R // nchunks, (k + 1) * R // nchunks)
    dbeta, dgamma, a, db32, dg32 = _grad_coefficients(sb, sg, gamma, invstd)
    dh = np.empty_like(h)
    _bn_max_grad_rows(gd, out, offsets, h, wn, scale, offset, mean32, inv32, a, db32, dg32, dh, 0, R)
    return dh, dgamma, dbeta


#: Below this many elements (rows x channels) the batch-norm and segment-max kernels run their chunks on
#: the calling thread. A parallel loop on Numba's workqueue layer costs ~0.1-0.2 ms to start (alone,
#: on the project's 2-core VM: 10k x 32 values forward + backward 0.94 ms on two threads, 0.35 ms on
#: one), and inside a training step its threads also compete with PyTorch's OpenMP threads, which
#: spin for a while after each operator. In DEFAULTS training steps, alternated step by step in one
#: process (30 each, 2 torch threads): every kernel parallel 0.446 s/step (median), serial below 2 M
#: values 0.415, below 8 M 0.388, all serial 0.396; STUDY steps (4 each): parallel 5.05, below 8 M
#: 4.96, below 32 M 4.93 (its largest arrays, 36 M values and more, stay parallel).
PARALLEL_MIN_ELEMENTS = 1 << 23


def run_parallel(elements: int) -> bool:
    """Whether a kernel over ``elements`` values should run its chunks on Numba's threads (see
    `PARALLEL_MIN_ELEMENTS`); the chunks, and so the numbers, are the same either way."""
    return numba.get_num_threads() > 1 and int(elements) >= PARALLEL_MIN_ELEMENTS


def parallel_chunks(threads: int) -> int:
    """Use ``threads`` (capped by Numba's pool) for the parallel kernels; returns the row chunks
    (four per thread) to pass them."""
    n = max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS))
    numba.set_num_threads(n)
    return 4 * n
