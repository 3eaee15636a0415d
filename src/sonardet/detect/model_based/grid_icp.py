"""Point-to-plane ICP with a Tukey kernel from many starts at once, against a precomputed nearest-sample grid.

The `ours` detector registers each scene crop onto a class's model surface from many starts (tumbled
resting poses, yaws, z levels, shifted restarts): about 3,000 short ICP runs a scene on a few hundred
voxel-thinned crop points each. Open3D's `registration_icp` is one call per start, builds a k-d tree
of the target on every call and searches it at every iteration; at this size that is most of its
0.6-1.1 ms per run. The model surface never changes, so here its nearest-sample search is done once:
`NearestSurfaceGrid` stores, for every cell of a regular grid around the surface (canonical frame), the
surface sample nearest to the cell (SciPy's exact Euclidean distance transform of the samples'
occupancy, with its nearest-feature indices), and `icp_point_to_plane_starts` runs the iterations
of all starts of one crop in one compiled call (Numba). No library offers ICP against a fixed
nearest-neighbour table or batched over starts, hence this module.

What is approximated: a correspondence is the sample nearest to the *cell* of the moved source point
(its cell's nearest occupied cell), not to the point itself: at most about one cell diagonal away
from the exact nearest sample. The point-to-plane residual measures the offset along that sample's
normal, which barely depends on which neighbouring sample of the same surface is taken (the grid's
cell is a quarter of the coarse surface's sample spacing). That cell's sample is refined by a greedy
walk on the samples' neighbour graph (`exact`, the detector's default in every stage): the exact
nearest sample for about 99 % of the points, and a correspondence that depends on the point, not on
which side of a cell boundary float noise puts it. The rest follows Open3D's
`TransformationEstimationPointToPlane` with `TukeyLoss` and `registration_icp`: the same residual,
Jacobian, weights, 6-vector update (rotation Rz Ry Rx), correspondence test (distance below the
stage's maximum), fitness, inlier RMSE and stopping rule (the change of fitness and of RMSE between
iterations both below the tolerances). `tests/test_grid_icp.py` compares it with Open3D.

Frames: source points are in the scene frame, the grid and its samples in the object's canonical
frame; a transform T (4x4) maps scene -> canonical, as in `registration.icp_scene_to_model`.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from ...jit import numba

__all__ = ["NearestSurfaceGrid", "icp_point_to_plane_starts"]


class NearestSurfaceGrid:
    """The nearest surface sample of every cell of a grid around a model surface (canonical frame).

    points, normals: (M,3) surface samples and their unit outward normals (m); cell_m: grid cell side
    (m); margin_m: how far beyond the samples' bounding box the grid reaches (the largest
    correspondence distance it serves: a point outside the grid is farther than that from every
    sample). Memory: one int32 per cell (about 2 M cells, 8 MB, for a 2 m object at 3 cm cells and a
    0.45 m margin).
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, cell_m: float, margin_m: float,
                 neighbours_n: int = 8):
        if cell_m <= 0 or margin_m < 0:
            raise ValueError(f"NearestSurfaceGrid: cell_m must be > 0 and margin_m >= 0 (got {cell_m}, {margin_m})")
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        self.normals = np.ascontiguousarray(normals, dtype=np.float64)
        if self.points.ndim != 2 or self.points.shape[1] != 3 or len(self.points) == 0:
            raise ValueError(f"NearestSurfaceGrid: points must be a non-empty (M,3) array, got {self.points.shape}")
        self.cell_m = float(cell_m)
        self.margin_m = float(margin_m)
        self.lo = self.points.min(0) - self.margin_m
        shape = np.ceil((self.points.max(0) + self.margin_m - self.lo) / self.cell_m).astype(np.int64) + 1
        cells = np.floor((self.points - self.lo) / self.cell_m).astype(np.int64)
        free = np.ones(tuple(shape), dtype=bool)
        free[cells[:, 0], cells[:, 1], cells[:, 2]] = False
        owner = np.full(tuple(shape), -1, dtype=np.int32)
        # Several samples in one cell: the first (lowest index) owns it, deterministically.
        order = np.arange(len(cells), dtype=np.int32)[::-1]
        owner[cells[order, 0], cells[order, 1], cells[order, 2]] = order
        idx = distance_transform_edt(free, return_distances=False, return_indices=True)
        self.nearest = np.ascontiguousarray(owner[idx[0], idx[1], idx[2]])
        del idx
        k = min(int(neighbours_n), len(self.points) - 1)
        if k > 0:
            nb = cKDTree(self.points).query(self.points, k=k + 1)[1][:, 1:]
        else:
            nb = np.zeros((len(self.points), 0))
        self.neighbours = np.ascontiguousarray(nb, dtype=np.int32)

    @property
    def shape(self) -> tuple:
        """Grid cells along x, y, z."""
        return self.nearest.shape

    def nearest_sample(self, pts_canonical: np.ndarray, exact: bool = True) -> np.ndarray:
        """Index (K,) of the nearest sample for canonical points (K,3), -1 outside the grid: the
        sample of the point's cell, refined by greedy descent on the neighbour graph when `exact`
        (see `icp_point_to_plane_starts`)."""
        p = np.asarray(pts_canonical, dtype=np.float64)
        c = np.floor((p - self.lo) / self.cell_m).astype(np.int64)
        ok = np.all((c >= 0) & (c < np.array(self.shape)), axis=1)
        out = np.full(len(p), -1, dtype=np.int64)
        out[ok] = self.nearest[c[ok, 0], c[ok, 1], c[ok, 2]]
        if exact:
            _descend(p, out, self.points, self.neighbours)
        return out

    def within(self, pts_canonical: np.ndarray, dist_m: float, near_m: float) -> np.ndarray:
        """Boolean (K,): canonical points whose distance to the surface is below `dist_m` (m), measured
        as `models.ClassModel.distance` does: along the nearest sample's normal when that sample is
        closer than `near_m`, else to the sample. The grid must reach max(dist_m, near_m) beyond the
        samples (`margin_m`)."""
        if max(dist_m, near_m) > self.margin_m + 1e-12:
            raise ValueError(f"NearestSurfaceGrid.within: max(dist_m, near_m) = {max(dist_m, near_m)} m exceeds "
                             f"the grid's margin {self.margin_m} m")
        p = np.ascontiguousarray(pts_canonical, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(p), dtype=np.bool_)
        _within(p, self.lo, self.cell_m, self.nearest, self.neighbours, self.points, self.normals, float(dist_m),
                float(near_m), out)
        return out


@numba.njit(cache=True, nogil=True)
def _descend_one(x, y, z, j, tpts, nbrs, max_steps=64):
    """From sample j, step to the neighbour closest to (x, y, z) while that gets closer (greedy descent
    on the samples' k-nearest-neighbour graph), at most max_steps steps. Returns (sample, squared
    distance)."""
    dx = x - tpts[j, 0]
    dy = y - tpts[j, 1]
    dz = z - tpts[j, 2]
    best = dx * dx + dy * dy + dz * dz
    for _ in range(max_steps):
        nxt = -1
        for m in range(nbrs.shape[1]):
            c = nbrs[j, m]
            dx = x - tpts[c, 0]
            dy = y - tpts[c, 1]
            dz = z - tpts[c, 2]
            d2 = dx * dx + dy * dy + dz * dz
            if d2 < best:
                best = d2
                nxt = c
        if nxt < 0:
            break
        j = nxt
    return j, best


@numba.njit(cache=True, nogil=True)
def _cell_sample(x, y, z, lo, cell, nearest):
    """The sample stored for the grid cell of (x, y, z), -1 outside the grid (NaN included)."""
    nx, ny, nz = nearest.shape
    fx = (x - lo[0]) / cell
    fy = (y - lo[1]) / cell
    fz = (z - lo[2]) / cell
    if not (fx >= 0.0 and fy >= 0.0 and fz >= 0.0 and fx < nx and fy < ny and fz < nz):
        return -1
    return nearest[int(fx), int(fy), int(fz)]


@numba.njit(cache=True, nogil=True)
def _descend(p, idx, tpts, nbrs):
    for i in range(p.shape[0]):
        if idx[i] >= 0:
            idx[i] = _descend_one(p[i, 0], p[i, 1], p[i, 2], idx[i], tpts, nbrs)[0]


@numba.njit(cache=True, nogil=True)
def _within(p, lo, cell, nearest, nbrs, tpts, tnrm, dist, near, out):
    near2 = near * near
    for i in range(p.shape[0]):
        j = _cell_sample(p[i, 0], p[i, 1], p[i, 2], lo, cell, nearest)
        if j < 0:
            continue
        j, d2 = _descend_one(p[i, 0], p[i, 1], p[i, 2], j, tpts, nbrs)
        if d2 < near2:
            dot = ((p[i, 0] - tpts[j, 0]) * tnrm[j, 0] + (p[i, 1] - tpts[j, 1]) * tnrm[j, 1]
                   + (p[i, 2] - tpts[j, 2]) * tnrm[j, 2])
            out[i] = abs(dot) < dist
        else:
            out[i] = d2 < dist * dist


@numba.njit(cache=True, nogil=True)
def _correspond(src, T, lo, cell, nearest, nbrs, tpts, max_corr2, steps, sel, moved):
    """Move src by T into `moved`; per source point the grid's nearest sample if within max_corr
    (its index in `sel`, -1 otherwise). Returns (number of correspondences, sum of squared distances)."""
    n = 0
    ss = 0.0
    for i in range(src.shape[0]):
        x = T[0, 0] * src[i, 0] + T[0, 1] * src[i, 1] + T[0, 2] * src[i, 2] + T[0, 3]
        y = T[1, 0] * src[i, 0] + T[1, 1] * src[i, 1] + T[1, 2] * src[i, 2] + T[1, 3]
        z = T[2, 0] * src[i, 0] + T[2, 1] * src[i, 1] + T[2, 2] * src[i, 2] + T[2, 3]
        moved[i, 0] = x
        moved[i, 1] = y
        moved[i, 2] = z
        sel[i] = -1
        j = _cell_sample(x, y, z, lo, cell, nearest)
        if j < 0:
            continue
        j, d2 = _descend_one(x, y, z, j, tpts, nbrs, steps)
        if d2 < max_corr2:
            sel[i] = j
            n += 1
            ss += d2
    return n, ss


@numba.njit(cache=True, nogil=True)
def _solve6(A, b, x):
    """Solve the symmetric 6x6 system A x = b by Cholesky (A is overwritten); False if A is not
    positive definite (a degenerate correspondence set: Open3D then leaves the pose unchanged)."""
    n = 6
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= A[j, k] * A[j, k]
        if not s > 1e-12:
            return False
        A[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= A[i, k] * A[j, k]
            A[i, j] = s / A[j, j]
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= A[i, k] * x[k]
        x[i] = s / A[i, i]
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= A[k, i] * x[k]
        x[i] = s / A[i, i]
    return True


@numba.njit(cache=True, nogil=True)
def _update_matrix(x, U):
    """Open3D's TransformVector6dToMatrix4d: U = [Rz(x2) Ry(x1) Rx(x0) | x3:6]."""
    ca, sa = np.cos(x[0]), np.sin(x[0])
    cb, sb = np.cos(x[1]), np.sin(x[1])
    cg, sg = np.cos(x[2]), np.sin(x[2])
    U[0, 0] = cg * cb
    U[0, 1] = cg * sb * sa - sg * ca
    U[0, 2] = cg * sb * ca + sg * sa
    U[1, 0] = sg * cb
    U[1, 1] = sg * sb * sa + cg * ca
    U[1, 2] = sg * sb * ca - cg * sa
    U[2, 0] = -sb
    U[2, 1] = cb * sa
    U[2, 2] = cb * ca
    U[0, 3] = x[3]
    U[1, 3] = x[4]
    U[2, 3] = x[5]
    U[3, 0] = 0.0
    U[3, 1] = 0.0
    U[3, 2] = 0.0
    U[3, 3] = 1.0


@numba.njit(cache=True, nogil=True)
def _icp_starts(src, T0, lo, cell, nearest, nbrs, tpts, tnrm, max_corr, tukey_k, n_iter, tol_fit, tol_rmse, steps,
                T_out, fitness, rmse, n_corr):
    n_src = src.shape[0]
    sel = np.empty(n_src, dtype=np.int64)
    moved = np.empty((n_src, 3))
    A = np.empty((6, 6))
    b = np.empty(6)
    x = np.empty(6)
    J = np.empty(6)
    U = np.empty((4, 4))
    max_corr2 = max_corr * max_corr
    for s in range(T0.shape[0]):
        T = T0[s].copy()
        n, ss = _correspond(src, T, lo, cell, nearest, nbrs, tpts, max_corr2, steps, sel, moved)
        fit = n / n_src
        err = np.sqrt(ss / n) if n > 0 else 0.0
        for _ in range(n_iter):
            A[:, :] = 0.0
            b[:] = 0.0
            for i in range(n_src):
                j = sel[i]
                if j < 0:
                    continue
                px, py, pz = moved[i, 0], moved[i, 1], moved[i, 2]
                nx_, ny_, nz_ = tnrm[j, 0], tnrm[j, 1], tnrm[j, 2]
                r = (px - tpts[j, 0]) * nx_ + (py - tpts[j, 1]) * ny_ + (pz - tpts[j, 2]) * nz_
                if abs(r) > tukey_k:
                    continue
                e = r / tukey_k
                w = (1.0 - e * e) * (1.0 - e * e)
                J[0] = py * nz_ - pz * ny_
                J[1] = pz * nx_ - px * nz_
                J[2] = px * ny_ - py * nx_
                J[3] = nx_
                J[4] = ny_
                J[5] = nz_
                for a in range(6):
                    wa = w * J[a]
                    b[a] -= wa * r
                    for c in range(a + 1):
                        A[a, c] += wa * J[c]
            if n > 0 and _solve6(A, b, x):
                _update_matrix(x, U)
                T = U @ T
            n_new, ss = _correspond(src, T, lo, cell, nearest, nbrs, tpts, max_corr2, steps, sel, moved)
            fit_new = n_new / n_src
            err_new = np.sqrt(ss / n_new) if n_new > 0 else 0.0
            done = abs(fit - fit_new) < tol_fit and abs(err - err_new) < tol_rmse
            n, fit, err = n_new, fit_new, err_new
            if done:
                break
        T_out[s] = T
        fitness[s] = fit
        rmse[s] = err
        n_corr[s] = n


def icp_point_to_plane_starts(src_scene: np.ndarray, T0: np.ndarray, grid: NearestSurfaceGrid, max_corr_m: float,
                              tukey_k_m: float, max_iter: int, tol_fitness: float = 1e-6,
                              tol_rmse_m: float = 1e-6, exact: bool = True):
    """Point-to-plane ICP with a Tukey kernel of width `tukey_k_m` of scene points `src_scene` (K,3)
    onto `grid`'s surface, from each start T0[s] (S,4,4; scene -> canonical), at most `max_iter`
    iterations with correspondences closer than `max_corr_m` (m). exact: refine each correspondence
    from the grid's sample to the nearest sample by greedy descent on the samples' neighbour graph
    (the exact nearest sample for about 99 % of the points, against about 80 % without; about twice
    the cost).

    Returns (T (S,4,4) scene -> canonical, fitness (S,) share of source points with a correspondence,
    inlier RMSE (S,) m, correspondences (S,) int) after the last iteration. The grid must reach at
    least `max_corr_m` beyond its samples (`margin_m`), or correspondences near its edge are lost.
    """
    if max_corr_m > grid.margin_m + 1e-12:
        raise ValueError(f"icp_point_to_plane_starts: max_corr_m {max_corr_m} exceeds the grid's margin "
                         f"{grid.margin_m} m; build the grid with margin_m >= the largest correspondence distance")
    src = np.ascontiguousarray(src_scene, dtype=np.float64)
    T0 = np.ascontiguousarray(np.asarray(T0, dtype=np.float64).reshape(-1, 4, 4))
    S = len(T0)
    T_out = np.empty((S, 4, 4))
    fitness = np.zeros(S)
    rmse = np.zeros(S)
    n_corr = np.zeros(S, dtype=np.int64)
    if S and len(src):
        _icp_starts(src, T0, grid.lo, grid.cell_m, grid.nearest, grid.neighbours, grid.points, grid.normals, float(max_corr_m),
                    float(tukey_k_m), int(max_iter), float(tol_fitness), float(tol_rmse_m), 64 if exact else 0,
                    T_out, fitness, rmse,
                    n_corr)
    else:
        T_out[:] = T0
    return T_out, fitness, rmse, n_corr
