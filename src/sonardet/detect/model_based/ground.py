"""Seabed (ground) removal: a global RANSAC plane (the source study) or a terrain-following grid DTM.

Both return a :class:`Ground`: the per-point height above the seabed (m) and a callable seabed
elevation z(x, y), so later stages can place objects on the seabed and reason in seabed-relative
heights. Frame: the detector's local frame (metres, z up); inputs are float64 (N,3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage as ndi

from ...jit import numba
from ...ransac import segment_plane

#: Planes steeper than 60 deg (walls) the RANSAC seabed sets aside before it gives up.
STEEP_PLANES_MAX = 3


@dataclass
class Ground:
    """A seabed model. `hab` (N,) is each input point's height above the seabed (m).

    Either a plane (`plane` = (a, b, c, d) with a x + b y + c z + d = 0, c > 0, unit normal) or a DTM
    raster (`dtm` (ny, nx) seabed elevation (m) at cell centres `x0 + (i + 0.5) cell_m`, ...).
    """

    hab: np.ndarray
    plane: np.ndarray | None = None
    dtm: np.ndarray | None = None
    x0: float = 0.0
    y0: float = 0.0
    cell_m: float = 1.0

    def z_at(self, x, y) -> np.ndarray:
        """Seabed elevation (m) at horizontal positions x, y (m, arrays of one shape)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        if self.plane is not None:
            a, b, c, d = self.plane
            return -(a * x + b * y + d) / c
        # Bilinear interpolation at cell-centre coordinates; clamped at the raster border.
        fx = (x - self.x0) / self.cell_m - 0.5
        fy = (y - self.y0) / self.cell_m - 0.5
        return ndi.map_coordinates(self.dtm, [np.ravel(fy), np.ravel(fx)], order=1, mode="nearest").reshape(x.shape)

    def height_above(self, xyz) -> np.ndarray:
        """Height (m) of points (N,3) above this seabed (vertical offset for a DTM; plane distance for a plane)."""
        p = np.asarray(xyz, dtype=np.float64)
        if self.plane is not None:
            return p @ self.plane[:3] + self.plane[3]
        return p[:, 2] - self.z_at(p[:, 0], p[:, 1])


def ransac_plane_ground(xyz: np.ndarray, distance_m: float, n_iter: int, seed: int) -> Ground:
    """Seabed as one RANSAC plane (Open3D `segment_plane`, 3-point samples), as in the source study.

    distance_m: inlier distance of the RANSAC (m); n_iter: RANSAC iterations; seed: Open3D's RANSAC
    seed (:func:`sonardet.ransac.segment_plane`: one thread, so the plane is deterministic). The plane normal is
    oriented up; `hab` is the signed distance of each point to the plane (m).

    The seabed is the largest plane flatter than 60 deg: when the largest one is steeper (a quay wall
    or a breakwater's face with more soundings than the seabed in front of it), its inliers are set
    aside and RANSAC runs on the rest, for up to `STEEP_PLANES_MAX` walls (ValueError after that). A
    cloud narrower than 2 x distance_m across is a strip whose plane is levelled across it
    (`_strip_plane`). Neither rule changes the plane of a cloud whose largest plane is flat and that
    is wider than that.
    """
    p = np.asarray(xyz, dtype=np.float64)
    if len(p) < 3:
        raise ValueError(f"a RANSAC plane needs at least 3 points, got {len(p)}")
    rest, steep = p, []
    for _ in range(STEEP_PLANES_MAX + 1):
        plane, inliers = _plane_of(rest, distance_m, n_iter, seed)
        if plane[2] >= 0.5:
            break
        # A wall (a quay, a breakwater's face) can hold more soundings than the seabed in front of it:
        # the seabed is the largest plane among the rest.
        steep.append(plane[:3].round(3).tolist())
        rest = np.delete(rest, inliers, axis=0)
        if len(rest) < 3:
            break
    if plane[2] < 0.5:
        raise ValueError(f"RANSAC found no seabed plane flatter than 60 deg (the largest planes' normals: {steep}); "
                         "is the cloud a seabed survey with z up?")
    g = Ground(hab=np.empty(0), plane=plane)
    g.hab = g.height_above(p)
    return g


def _plane_of(p: np.ndarray, distance_m: float, n_iter: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The largest plane of p (N>=3, 3) (a, b, c, d; unit normal, c >= 0) and its inlier indices: the
    strip rule's levelled plane (`_strip_plane`, every point an inlier) or Open3D's seeded RANSAC."""
    plane = _strip_plane(p, distance_m)
    if plane is not None:
        return plane, np.arange(len(p))
    plane, inliers = segment_plane(p, distance_m, 3, n_iter, seed, probability=1.0)
    n = np.linalg.norm(plane[:3])
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError("RANSAC found no seabed plane (degenerate input)")
    plane = plane / n
    return (-plane if plane[2] < 0 else plane), np.asarray(inliers, dtype=np.int64)


def _strip_plane(p: np.ndarray, distance_m: float) -> np.ndarray | None:
    """The seabed plane (a, b, c, d), unit normal, c > 0) of soundings p (N,3, m) whose xy footprint is
    a strip narrower than 2 x distance_m across its principal direction, else None.

    In such a strip a vertical plane along its middle holds every sounding within distance_m, as the
    seabed does, and RANSAC picks whichever of the two fits tighter: for a strip narrower than the
    soundings' vertical noise, or one of collinear soundings, that is the vertical one (a sliver of a
    survey: a tile's edge, one beam's soundings, or many soundings at one spot), and the detection
    stopped on the steepness check. Here the seabed is levelled across the strip and fitted along it
    (z = a s + c, s along the strip): by least squares, refitted three times to the soundings within
    distance_m of the last line (at least the closer half: objects on the strip do not tilt it), or,
    where the strip is also shorter than 2 x distance_m (one spot), level at the median height. It
    is the seabed if at least half the soundings lie within distance_m of it; else the strip is a
    wall seen edge-on or a column of soundings (None: RANSAC's steep plane sets it aside). Wider
    clouds go to RANSAC as before, so no survey or scene of any size changes."""
    xy = p[:, :2] - p[:, :2].mean(0)
    _, _, vt = np.linalg.svd(xy, full_matrices=False)
    along, across = xy @ vt[0], xy @ vt[1]
    if np.ptp(across) >= 2.0 * distance_m:
        return None
    z = p[:, 2]
    if np.ptp(along) < 2.0 * distance_m:
        a, c = 0.0, float(np.median(z))
    else:
        design = np.column_stack([along, np.ones(len(p))])
        keep = np.ones(len(p), dtype=bool)
        for _ in range(3):
            (a, c), *_ = np.linalg.lstsq(design[keep], z[keep], rcond=None)
            r = np.abs(z - (a * along + c))
            keep = r < distance_m
            if 2 * keep.sum() < len(p):
                keep = r <= np.median(r)
    if 2 * np.count_nonzero(np.abs(z - (a * along + c)) < distance_m) < len(p):
        return None
    # z = a (u . (xy - m)) + c with u = vt[0], m the xy mean, as a x + b y + c z + d = 0 with c > 0:
    plane = np.array([-a * vt[0, 0], -a * vt[0, 1], 1.0, a * float(vt[0] @ p[:, :2].mean(0)) - c])
    return plane / np.linalg.norm(plane[:3])


def _fill_nearest(a: np.ndarray) -> np.ndarray:
    """Fill NaN cells with the value of the nearest finite cell (Euclidean, in cells)."""
    bad = ~np.isfinite(a)
    if not bad.any():
        return a
    if bad.all():
        raise ValueError("no finite cells to interpolate the seabed from")
    idx = ndi.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return a[tuple(idx)]


def _robust_plane(a: np.ndarray, n_iter: int = 3, keep_m: float = 0.3) -> np.ndarray:
    """Least-squares plane through a raster (values at cell indices), refitted on the cells no more
    than `keep_m` above it (objects stand above the seabed); returns the plane evaluated per cell."""
    iy, ix = np.mgrid[0:a.shape[0], 0:a.shape[1]]
    A = np.c_[ix.ravel(), iy.ravel(), np.ones(a.size)].astype(np.float64)
    z = a.ravel()
    use = np.ones(a.size, dtype=bool)
    coef = np.zeros(3)
    for _ in range(n_iter):
        if use.sum() < 3:
            break
        coef = np.linalg.lstsq(A[use], z[use], rcond=None)[0]
        use = z - A @ coef <= keep_m
    return (A @ coef).reshape(a.shape)


@numba.njit(cache=True, nogil=True)
def _cell_medians(flat, z, n_cells):
    """Median of z per cell index `flat` (0..n_cells-1; NaN for empty cells): the points are bucketed by
    cell (counting sort, O(N)) and each cell's few values sorted on their own, instead of one lexsort
    of all N points. The median of an even count is the mean of the two middle values, as np.median."""
    counts = np.zeros(n_cells + 1, dtype=np.int64)
    for k in range(flat.shape[0]):
        counts[flat[k] + 1] += 1
    for c in range(n_cells):
        counts[c + 1] += counts[c]
    pos = counts[:-1].copy()
    zs = np.empty(z.shape[0])
    for k in range(flat.shape[0]):
        zs[pos[flat[k]]] = z[k]
        pos[flat[k]] += 1
    out = np.full(n_cells, np.nan)
    for c in range(n_cells):
        a, b = counts[c], counts[c + 1]
        if b > a:
            v = np.sort(zs[a:b])
            n = b - a
            out[c] = 0.5 * (v[(n - 1) // 2] + v[n // 2])
    return out


def _cell_stat(ix, iy, z, shape, stat: str) -> np.ndarray:
    """Per-cell min or median of z over cells (iy, ix) of a raster of `shape`; NaN for empty cells."""
    flat = iy * shape[1] + ix
    out = np.full(shape[0] * shape[1], np.nan)
    if len(z) == 0:
        return out.reshape(shape)
    if stat == "min":
        m = np.full(shape[0] * shape[1], np.inf)
        np.minimum.at(m, flat, z)
        out[np.isfinite(m)] = m[np.isfinite(m)]
        return out.reshape(shape)
    return _cell_medians(np.ascontiguousarray(flat, dtype=np.int64), np.ascontiguousarray(z, dtype=np.float64),
                         shape[0] * shape[1]).reshape(shape)


def grid_ground(xyz: np.ndarray, cell_m: float, window_m: float, refine_cell_m: float,
                refine_bands_m=(0.3, 0.12), smooth_cells: float = 1.0) -> Ground:
    """Terrain-following seabed: grid minimum, grey opening, then median refinement in height bands.

    1. per `cell_m` cell the lowest point; empty cells take the nearest cell's value;
    2. a grey opening with a `window_m` square window removes everything narrower than the window
       (objects, piles, rocks), giving a first DTM that follows slopes and long-wave relief;
    3. for each band in `refine_bands_m` (m, decreasing): points within +-band of the current DTM are
       seabed candidates; their per-cell median on a `refine_cell_m` grid, hole-filled and smoothed
       with a Gaussian of `smooth_cells` cells, becomes the new DTM (a minimum sits below a noisy
       surface; the median of the band does not).
    Returns a :class:`Ground` with the final DTM raster (cell `refine_cell_m`) and `hab` per point.
    """
    p = np.asarray(xyz, dtype=np.float64)
    # Grids are anchored at multiples of the cell in the local frame (not at the cloud's corner), so a
    # crop of the survey (a tile) sees the same cells as the whole survey does.
    x0, y0 = (float(np.floor(p[:, k].min() / cell_m) * cell_m) for k in (0, 1))

    def grid(cell):
        nx = int(np.floor((p[:, 0].max() - x0) / cell)) + 1
        ny = int(np.floor((p[:, 1].max() - y0) / cell)) + 1
        ix = np.minimum(((p[:, 0] - x0) / cell).astype(np.int64), nx - 1)
        iy = np.minimum(((p[:, 1] - y0) / cell).astype(np.int64), ny - 1)
        return ix, iy, (ny, nx)

    ix, iy, shape = grid(cell_m)
    zmin = _fill_nearest(_cell_stat(ix, iy, p[:, 2], shape, "min"))
    w = max(1, int(round(window_m / cell_m)))
    # The opening runs on the minima detrended by a robust plane: a flat window then follows the
    # regional slope, and the raster border (padded with the nearest value) does not cut into slopes.
    trend = _robust_plane(zmin)
    dtm = ndi.grey_opening(zmin - trend, size=(w, w), mode="nearest") + trend
    g = Ground(hab=np.empty(0), dtm=dtm, x0=x0, y0=y0, cell_m=cell_m)
    hab = g.height_above(p)
    rix, riy, rshape = grid(refine_cell_m)
    for band in refine_bands_m:
        sel = np.abs(hab) <= band
        med = _cell_stat(rix[sel], riy[sel], p[sel, 2], rshape, "median")
        if not np.isfinite(med).any():
            break
        med = _fill_nearest(med)
        if smooth_cells > 0:
            med = ndi.gaussian_filter(med, smooth_cells, mode="nearest")
        g = Ground(hab=np.empty(0), dtm=med, x0=x0, y0=y0, cell_m=refine_cell_m)
        hab = g.height_above(p)
    g.hab = hab
    return g


def seabed(xyz: np.ndarray, p: dict) -> Ground:
    """The seabed model a detector variant's parameters ask for: `ground_method` 'ransac' (one plane
    fitted on a seeded random subset of `ransac_sample_n` points) or 'grid' (`grid_ground`); `hab` is
    filled for every point of xyz."""
    if p["ground_method"] == "ransac":
        n = int(p["ransac_sample_n"])
        if len(xyz) > n:
            pick = np.sort(np.random.default_rng(p["seed"]).choice(len(xyz), n, replace=False))
            sub = xyz[pick]
        else:
            sub = xyz
        g = ransac_plane_ground(sub, p["ransac_distance_m"], p["ransac_iter_n"], p["seed"])
        g.hab = g.height_above(xyz)
        return g
    if p["ground_method"] != "grid":
        raise ValueError(f"ground_method must be 'grid' or 'ransac', got {p['ground_method']!r}")
    return grid_ground(xyz, p["ground_cell_m"], p["ground_window_m"], p["ground_refine_cell_m"],
                       p["ground_refine_bands_m"])
