"""Fixed-radius "is any scene point near" tests for the coverage score (sonardet.detect.model_based.scoring).

The coverage term asks, for every point of every template view of a hypothesis (thousands per
hypothesis, hundreds of hypotheses per scene), whether a scene point lies within `coverage_m` of it. A
k-d tree answers that with a nearest-neighbour search per point (SciPy's ``cKDTree.query`` with a
distance bound) and has to be built for each hypothesis' neighbourhood first. A uniform grid of
columns of side `radius_m`, each sorted by height, answers the same question exactly by looking at
the 3 x 3 columns around the query, only at their points within the radius in z (binary search),
and stopping at the first point closer than the radius: no library offers this
any-within-radius test as one compiled call, so it is written here (Numba, compiled once and cached
on disk).
"""

from __future__ import annotations

import numpy as np

from ...jit import numba

__all__ = ["NearGrid", "xy_cells"]


@numba.njit(cache=True, nogil=True)
def _any_within(q, pts, start, lo_x, lo_y, cell, nx, ny, r, r2):
    """Boolean (K,): some point of `pts` (sorted by column, then z; column c holding
    pts[start[c]:start[c+1]]) lies at a squared distance below r2 (= r^2) of q[k]."""
    out = np.zeros(q.shape[0], dtype=np.bool_)
    for k in range(q.shape[0]):
        fx = (q[k, 0] - lo_x) / cell
        fy = (q[k, 1] - lo_y) / cell
        if fx < -1.0 or fy < -1.0 or fx >= nx + 1.0 or fy >= ny + 1.0:
            continue  # more than one column off the grid: no point within the radius
        cx = int(np.floor(fx))
        cy = int(np.floor(fy))
        zlo = q[k, 2] - r
        zhi = q[k, 2] + r
        found = False
        for ix in range(max(cx - 1, 0), min(cx + 2, nx)):
            for iy in range(max(cy - 1, 0), min(cy + 2, ny)):
                c = ix * ny + iy
                # The column is sorted by z: start at the first point above qz - r (binary search).
                a, b = start[c], start[c + 1]
                while a < b:
                    mid = (a + b) // 2
                    if pts[mid, 2] <= zlo:
                        a = mid + 1
                    else:
                        b = mid
                for m in range(a, start[c + 1]):
                    if pts[m, 2] >= zhi:
                        break
                    dx = pts[m, 0] - q[k, 0]
                    dy = pts[m, 1] - q[k, 1]
                    dz = pts[m, 2] - q[k, 2]
                    if dx * dx + dy * dy + dz * dz < r2:
                        found = True
                        break
                if found:
                    break
            if found:
                break
        out[k] = found
    return out


@numba.njit(cache=True, nogil=True)
def xy_cells(pts, cell, pad_cells):
    """The xy cell indices (ix, iy) (N,) of points (N,3, N > 0) on a grid of side `cell` whose origin
    (lo_x, lo_y) is their smallest x and y less `pad_cells` cells: floor((x - lo_x) / cell), as NumPy
    computes it. Returns (ix, iy, lo_x, lo_y)."""
    n = pts.shape[0]
    lo_x = pts[0, 0]
    lo_y = pts[0, 1]
    for k in range(1, n):
        lo_x = min(lo_x, pts[k, 0])
        lo_y = min(lo_y, pts[k, 1])
    lo_x -= pad_cells * cell
    lo_y -= pad_cells * cell
    ix = np.empty(n, dtype=np.int64)
    iy = np.empty(n, dtype=np.int64)
    for k in range(n):
        ix[k] = int(np.floor((pts[k, 0] - lo_x) / cell))
        iy[k] = int(np.floor((pts[k, 1] - lo_y) / cell))
    return ix, iy, lo_x, lo_y


@numba.njit(cache=True, nogil=True)
def _columns(pts, cell):
    """The points (N,3, N > 0) sorted by column (ix * ny + iy of the `cell` grid from their smallest x
    and y, lo_x and lo_y), then by z within a column; the columns' start offsets (nx * ny + 1,), nx,
    ny, lo_x and lo_y. A counting sort by column and an insertion sort of each column's few heights
    (the order of equal heights does not matter to the test)."""
    n = pts.shape[0]
    ix, iy, lo_x, lo_y = xy_cells(pts, cell, 0.0)
    nx = ix.max() + 1
    ny = iy.max() + 1
    start = np.zeros(nx * ny + 1, dtype=np.int64)
    for k in range(n):
        start[ix[k] * ny + iy[k] + 1] += 1
    for c in range(nx * ny):
        start[c + 1] += start[c]
    pos = start[:-1].copy()
    out = np.empty((n, 3))
    for k in range(n):
        c = ix[k] * ny + iy[k]
        out[pos[c], :] = pts[k, :]
        pos[c] += 1
    # Insertion sort of each column by z, in place: a column holds a few points, and most of a
    # hypothesis' columns none, so a sort call (and its buffer) per column cost more than the sorting.
    for c in range(nx * ny):
        a, b = start[c], start[c + 1]
        for m in range(a + 1, b):
            x, y, z = out[m, 0], out[m, 1], out[m, 2]
            j = m - 1
            while j >= a and out[j, 2] > z:
                out[j + 1, 0] = out[j, 0]
                out[j + 1, 1] = out[j, 1]
                out[j + 1, 2] = out[j, 2]
                j -= 1
            out[j + 1, 0] = x
            out[j + 1, 1] = y
            out[j + 1, 2] = z
    return out, start, nx, ny, lo_x, lo_y


class NearGrid:
    """Points (N,3, m) in xy columns of side `radius_m`, for :meth:`any_within` tests at that radius."""

    def __init__(self, pts: np.ndarray, radius_m: float):
        pts = np.ascontiguousarray(pts, dtype=np.float64)
        if not radius_m > 0:
            raise ValueError(f"NearGrid radius must be positive, got {radius_m}")
        self.radius_m = float(radius_m)
        if len(pts) == 0:
            self.lo = np.zeros(2)
            self.nx = self.ny = 0
            self.pts, self.start = pts.reshape(0, 3), np.zeros(1, dtype=np.int64)
            return
        self.pts, self.start, self.nx, self.ny, lo_x, lo_y = _columns(pts, self.radius_m)
        self.lo = np.array([lo_x, lo_y])

    def any_within(self, q: np.ndarray) -> np.ndarray:
        """Boolean (K,): query points q (K,3, m) with a grid point closer than the radius (strictly)."""
        q = np.ascontiguousarray(q, dtype=np.float64).reshape(-1, 3)
        if self.nx == 0 or len(q) == 0:
            return np.zeros(len(q), dtype=bool)
        return _any_within(q, self.pts, self.start, float(self.lo[0]), float(self.lo[1]), self.radius_m,
                           self.nx, self.ny, self.radius_m, self.radius_m * self.radius_m)
