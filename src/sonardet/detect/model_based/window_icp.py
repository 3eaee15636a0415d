"""Point-to-point ICP of a template onto a window's points, compiled: the `paper` variant's registration.

The `paper` variant registers one template view onto every sliding window that holds enough points:
about 2,000 windows a default scene, each an ICP (up to `icp_max_iter` iterations), a refinement (up
to `icp_refine_iter` more, at a tighter correspondence distance) and an evaluation at the first
distance. Open3D's `registration_icp` and `evaluate_registration` do this at 2.9-4.0 ms a window (one
thread), and they hold their search structure only for one call: three k-d trees of the same window
points a window, and two point clouds copied in and out of Python per call. Here the window's points
are bucketed once into a regular grid (`WindowGrid`) that serves all three steps, and each step runs
in one compiled call (Numba). No library offers point-to-point ICP on a search structure kept across calls, hence this
module.

What it computes is Open3D's `RegistrationICP` with `TransformationEstimationPointToPoint` (without
scaling), step for step:

* correspondences: for every source point in order, the nearest target point, kept when its squared
  distance is below the squared correspondence distance (Open3D's hybrid search with one
  neighbour); the squared distances summed in source order; fitness = correspondences / source
  points, inlier RMSE = sqrt(sum / correspondences), both 0 without correspondences;
* transformation: the Kabsch/Umeyama rotation of the correspondences' centred cross-covariance
  (its SVD, the last singular direction flipped when the determinants' product is negative) and the
  translation between the means; the identity without correspondences;
* loop: the source moved by the initial pose, correspondences, then per iteration: the update, the
  pose = update x pose, the source moved by the update, new correspondences, and a stop when the
  changes of fitness and of inlier RMSE are both below the tolerances;
* evaluation: the template moved by a pose, one correspondence pass.

It differs from Open3D only in the last bits: the SVD is LAPACK's, not Eigen's Jacobi SVD, the means
are summed in another order, and between two target points at exactly the same distance another one
may be taken. `tests/test_window_icp.py` compares poses, fitness and RMSE with Open3D on windows of a
synthetic surface, `tests/test_model_based.py` the `paper` detections of both on a simulated scene;
the variant's `icp_backend` "open3d" runs Open3D's functions instead.

Frames: template points in the object's canonical frame, window points in the detector's local scene
frame (m); a pose T (4x4) maps canonical -> scene, as in `registration.icp_point_to_point`.
"""

from __future__ import annotations

import numpy as np

from ...jit import numba

__all__ = ["WindowGrid", "evaluate", "icp"]

#: Most grid cells a window gets; a window spread wider (outliers far above the seabed) gets larger
#: cells, which only costs search time.
MAX_CELLS = 1 << 20

_JIT = dict(cache=True, nogil=True)


class WindowGrid:
    """A window's points (M,3, scene frame, m) bucketed into cubic cells of side `cell_m` (m; doubled
    until the grid has at most `MAX_CELLS` cells). A search visits the cells a ball of the
    correspondence distance reaches, so any distance works; cells about that distance wide were the
    fastest measured (`paper` uses its larger one). `sorted`: the points in cell order, `start`: each
    cell's first index into it (n_cells + 1), `order`: each sorted point's index in `points`."""

    def __init__(self, points: np.ndarray, cell_m: float):
        pts = np.ascontiguousarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.isfinite(pts).all():
            raise ValueError(f"WindowGrid: points must be a non-empty finite (M,3) array, got shape {pts.shape}")
        if not cell_m > 0:
            raise ValueError(f"WindowGrid: cell_m must be > 0, got {cell_m}")
        self.origin = pts.min(0)
        span = pts.max(0) - self.origin
        cell = float(cell_m)
        while np.prod(np.floor(span / cell) + 1) > MAX_CELLS:
            cell *= 2.0
        self.cell_m = cell
        self.dims = (np.floor(span / cell) + 1).astype(np.int64)
        self.start, self.order, self.sorted = _bucket(pts, self.origin, cell, self.dims)


def icp(template: np.ndarray, grid: WindowGrid, T0: np.ndarray, max_corr_m: float, max_iter: int,
        relative_fitness: float, relative_rmse: float) -> tuple[np.ndarray, float, float, int]:
    """Open3D's point-to-point `registration_icp` of `template` (K,3, canonical) onto the grid's window
    points from pose `T0` (4x4), with correspondence distance `max_corr_m` (m) and at most
    `max_iter` iterations, stopping when fitness and inlier RMSE change by less than
    `relative_fitness` and `relative_rmse` (m) (Open3D's convergence criteria; the callers pass
    `registration.ICP_RELATIVE_*`). Returns the pose (4x4), fitness, inlier RMSE (m) and the number of
    correspondences of the last pass."""
    _check_distance(max_corr_m)
    src = np.ascontiguousarray(template, dtype=np.float64)
    T, fit, rmse, n = _icp(src, np.ascontiguousarray(T0, dtype=np.float64), grid.sorted, grid.start, grid.origin,
                           grid.cell_m, grid.dims, float(max_corr_m), int(max_iter), float(relative_fitness),
                           float(relative_rmse))
    return T, float(fit), float(rmse), int(n)


def evaluate(template: np.ndarray, grid: WindowGrid, T: np.ndarray, max_corr_m: float) -> tuple[float, float, int]:
    """Open3D's `evaluate_registration` of `template` (K,3, canonical) moved by pose `T` (4x4) against
    the grid's window points at correspondence distance `max_corr_m` (m): fitness, inlier RMSE (m) and
    the number of correspondences."""
    _check_distance(max_corr_m)
    src = _moved(np.ascontiguousarray(template, dtype=np.float64), np.ascontiguousarray(T, dtype=np.float64))
    n, e2 = _correspond(src, grid.sorted, grid.start, grid.origin, grid.cell_m, grid.dims, float(max_corr_m),
                        np.full(len(src), -1, np.int64))
    fit, rmse = _fitness_rmse(n, e2, len(src))
    return float(fit), float(rmse), int(n)


def _check_distance(max_corr_m: float) -> None:
    if not 0 < max_corr_m < np.inf:
        raise ValueError(f"correspondence distance must be > 0 and finite, got {max_corr_m} m")


@numba.njit(**_JIT)
def _bucket(pts, origin, cell, dims):
    """Counting sort of the points by cell (x-major, then y, then z; points of a cell in input order):
    the cells' start offsets (n_cells + 1), the sorted points' input indices and the sorted points."""
    n = pts.shape[0]
    nx, ny, nz = dims[0], dims[1], dims[2]
    key = np.empty(n, np.int64)
    start = np.zeros(nx * ny * nz + 1, np.int64)
    for i in range(n):
        ix = min(int(np.floor((pts[i, 0] - origin[0]) / cell)), nx - 1)
        iy = min(int(np.floor((pts[i, 1] - origin[1]) / cell)), ny - 1)
        iz = min(int(np.floor((pts[i, 2] - origin[2]) / cell)), nz - 1)
        k = (ix * ny + iy) * nz + iz
        key[i] = k
        start[k + 1] += 1
    for k in range(nx * ny * nz):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    sorted_pts = np.empty((n, 3), np.float64)
    for i in range(n):
        j = fill[key[i]]
        fill[key[i]] += 1
        order[j] = i
        sorted_pts[j, 0] = pts[i, 0]
        sorted_pts[j, 1] = pts[i, 1]
        sorted_pts[j, 2] = pts[i, 2]
    return start, order, sorted_pts


@numba.njit(inline="always")
def _cell_range(q, r, o, cell, n):
    """First and last cell index along one axis that a ball of radius r around q reaches; (1, 0), an
    empty range that stays inside the cell table, when it reaches none."""
    lo = np.floor((q - r - o) / cell)
    hi = np.floor((q + r - o) / cell)
    if hi < 0.0 or lo > n - 1:
        return 1, 0
    return int(max(lo, 0.0)), int(min(hi, n - 1.0))


@numba.njit(inline="always")
def _gap(q, lo, cell):
    """Distance (m) along one axis from coordinate q to the cell [lo, lo + cell] (0 inside)."""
    if q < lo:
        return lo - q
    if q > lo + cell:
        return q - lo - cell
    return 0.0


@numba.njit(inline="always")
def _scan(tgt, j0, j1, qx, qy, qz, best, bj):
    """The nearest of the sorted target points j0..j1-1 to q if nearer than `best` (squared, m^2)."""
    for j in range(j0, j1):
        dx = qx - tgt[j, 0]
        dy = qy - tgt[j, 1]
        dz = qz - tgt[j, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best:
            best = d2
            bj = j
    return best, bj


@numba.njit(**_JIT)
def _correspond(src, tgt, start, origin, cell, dims, r, out):
    """For each source point (in order) the nearest target point (sorted index into `tgt`) with squared
    distance < r^2, or -1, in `out`; returns (correspondences, sum of their squared distances).

    `out` holds on entry each point's previous nearest point (an ICP iteration moves the points a
    little) or -1: its distance bounds the search from the start. The point's own cell is searched
    next; a cell of the ball's block is skipped when the box's distance to the point is no less than
    the nearest distance found. The result is the exact nearest point either way."""
    nx, ny, nz = dims[0], dims[1], dims[2]
    ox, oy, oz = origin[0], origin[1], origin[2]
    r2 = r * r
    n = 0
    e2 = 0.0
    for i in range(src.shape[0]):
        qx, qy, qz = src[i, 0], src[i, 1], src[i, 2]
        best = r2
        bj = -1
        if out[i] >= 0:
            best, bj = _scan(tgt, out[i], out[i] + 1, qx, qy, qz, best, bj)
        out[i] = -1
        fx, fy, fz = np.floor((qx - ox) / cell), np.floor((qy - oy) / cell), np.floor((qz - oz) / cell)
        home = -1
        if 0.0 <= fx < nx and 0.0 <= fy < ny and 0.0 <= fz < nz:
            home = (int(fx) * ny + int(fy)) * nz + int(fz)
            best, bj = _scan(tgt, start[home], start[home + 1], qx, qy, qz, best, bj)
        rr = np.sqrt(best)  # the cells that can still hold a nearer point lie within this
        x0, x1 = _cell_range(qx, rr, ox, cell, nx)
        y0, y1 = _cell_range(qy, rr, oy, cell, ny)
        z0, z1 = _cell_range(qz, rr, oz, cell, nz)
        for ix in range(x0, x1 + 1):
            gx = _gap(qx, ox + ix * cell, cell)
            gx2 = gx * gx
            if gx2 >= best:
                continue
            for iy in range(y0, y1 + 1):
                gy = _gap(qy, oy + iy * cell, cell)
                gxy2 = gx2 + gy * gy
                if gxy2 >= best:
                    continue
                base = (ix * ny + iy) * nz
                for iz in range(z0, z1 + 1):
                    c = base + iz
                    if c == home or start[c] == start[c + 1]:
                        continue
                    gz = _gap(qz, oz + iz * cell, cell)
                    if gxy2 + gz * gz >= best:
                        continue
                    best, bj = _scan(tgt, start[c], start[c + 1], qx, qy, qz, best, bj)
        if bj >= 0:
            out[i] = bj
            e2 += best
            n += 1
    return n, e2


@numba.njit(**_JIT)
def _fitness_rmse(n, e2, n_src):
    if n == 0:
        return 0.0, 0.0
    return n / n_src, np.sqrt(e2 / n)


@numba.njit(**_JIT)
def _moved(src, T):
    """Points (K,3) moved by the 4x4 transform T."""
    out = np.empty_like(src)
    for i in range(src.shape[0]):
        x, y, z = src[i, 0], src[i, 1], src[i, 2]
        for r in range(3):
            out[i, r] = T[r, 0] * x + T[r, 1] * y + T[r, 2] * z + T[r, 3]
    return out


@numba.njit(**_JIT)
def _det3(M):
    return (M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]) - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
            + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]))


@numba.njit(**_JIT)
def _kabsch(src, tgt, corr, n):
    """The rigid update (4x4) that moves the corresponding source points onto their target points in
    the least-squares sense (Umeyama without scaling); the identity without correspondences."""
    U4 = np.eye(4)
    if n == 0:
        return U4
    ms = np.zeros(3)
    mt = np.zeros(3)
    for i in range(src.shape[0]):
        j = corr[i]
        if j >= 0:
            for a in range(3):
                ms[a] += src[i, a]
                mt[a] += tgt[j, a]
    ms /= n
    mt /= n
    sigma = np.zeros((3, 3))
    for i in range(src.shape[0]):
        j = corr[i]
        if j >= 0:
            for a in range(3):
                ta = tgt[j, a] - mt[a]
                for b in range(3):
                    sigma[a, b] += ta * (src[i, b] - ms[b])
    sigma /= n
    U, _, Vt = np.linalg.svd(sigma)
    if _det3(U) * _det3(Vt) < 0:
        U[:, 2] = -U[:, 2]
    R = U @ Vt
    U4[:3, :3] = R
    for a in range(3):
        U4[a, 3] = mt[a] - (R[a, 0] * ms[0] + R[a, 1] * ms[1] + R[a, 2] * ms[2])
    return U4


@numba.njit(**_JIT)
def _icp(template, T0, tgt, start, origin, cell, dims, r, max_iter, tol_fit, tol_rmse):
    """The ICP loop of the module doc; returns (pose, fitness, inlier RMSE, correspondences)."""
    src = _moved(template, T0)
    T = T0.copy()
    corr = np.full(src.shape[0], -1, np.int64)
    n, e2 = _correspond(src, tgt, start, origin, cell, dims, r, corr)
    fit, rmse = _fitness_rmse(n, e2, src.shape[0])
    for _ in range(max_iter):
        upd = _kabsch(src, tgt, corr, n)
        T = upd @ T
        src = _moved(src, upd)
        fit0, rmse0 = fit, rmse
        n, e2 = _correspond(src, tgt, start, origin, cell, dims, r, corr)
        fit, rmse = _fitness_rmse(n, e2, src.shape[0])
        if abs(fit0 - fit) < tol_fit and abs(rmse0 - rmse) < tol_rmse:
            break
    return T, fit, rmse, n
