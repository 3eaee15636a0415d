"""Where to look: sliding windows (the source study) or proposals from the height-above-seabed map.

Frames: the detector's local frame (metres). A raster has cell `cell_m`, origin (x0, y0) at the
lower-left corner of cell (0, 0); cell (i, j) covers x in [x0 + j cell, x0 + (j+1) cell), y likewise
with i. Proposals are (x, y) positions of the class's canonical origin (base centre) plus a yaw.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage as ndi

from ...jit import numba


@dataclass
class Raster:
    """Height above seabed (m) per BEV cell: the highest point's; NaN where the sonar saw nothing."""

    h: np.ndarray
    x0: float
    y0: float
    cell_m: float

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Row and column indices (clipped into the raster) of positions (K,2)."""
        j = np.clip(((xy[:, 0] - self.x0) / self.cell_m).astype(np.int64), 0, self.h.shape[1] - 1)
        i = np.clip(((xy[:, 1] - self.y0) / self.cell_m).astype(np.int64), 0, self.h.shape[0] - 1)
        return i, j

    def centre(self, i, j) -> np.ndarray:
        """Cell centres (K,2) of row/column indices."""
        x = self.x0 + (np.asarray(j) + 0.5) * self.cell_m
        y = self.y0 + (np.asarray(i) + 0.5) * self.cell_m
        return np.stack([x, y], -1)


def height_raster(xy: np.ndarray, hab: np.ndarray, cell_m: float, x0: float, y0: float, shape,
                  fill_cells: int = 1) -> Raster:
    """Max height above seabed (m) of points (xy (N,2), hab (N,)) per cell of a raster of `shape`.

    Soundings are sparser than fine cells (a ping line every few decimetres), so empty cells take the
    maximum of the cells within `fill_cells` (a grey dilation restricted to empty cells); cells with
    no point that near stay NaN (no data: shadow).
    """
    r = Raster(np.full(shape, -np.inf), x0, y0, cell_m)
    if len(xy):
        i, j = r.cell_of(xy)
        flat = r.h.ravel()
        np.maximum.at(flat, i * shape[1] + j, hab)
        r.h = flat.reshape(shape)
    if fill_cells > 0:
        empty = ~np.isfinite(r.h)
        grown = ndi.grey_dilation(r.h, size=(2 * fill_cells + 1,) * 2, mode="constant", cval=-np.inf)
        r.h[empty] = grown[empty]
    r.h[~np.isfinite(r.h)] = np.nan
    return r


def vote_map(r: Raster, kernels: list, occupied_min_m: float, c: Correlator | None = None):
    """Share of each kernel's footprint (cells the class's top surface covers) that holds points above
    `occupied_min_m`, best over the kernels, with the index of the best kernel. A plain occupancy
    correlation (Hough-like): partial objects (a ring half under another) still peak at their centre.
    c: a `Correlator` of r shared with other calls on the same raster (its spectra are reused)."""
    c = Correlator(r) if c is None else c.check(r)
    best = np.full(r.h.shape, -1.0)
    arg = np.zeros(r.h.shape, dtype=np.int64)
    for k, ker in enumerate(kernels):
        ks = ker.height.shape
        v = c.corr(c.raster_spectrum("vocc", ks, occupied_min_m), ker.footprint_spectrum(c, occupied_min_m), ks) \
            / max(ker.footprint_cells(occupied_min_m), 1.0)
        better = v > best
        best[better] = v[better]
        arg[better] = k
    return best, arg


@dataclass
class Kernel:
    """A class's top-surface height map (m above its base) at one yaw, on a square grid of BEV cells
    centred on the canonical origin, with the disk support it is compared over."""

    yaw_rad: float
    height: np.ndarray
    support: np.ndarray
    #: Spectra for the last padded shape used (a scene's rounds, and scenes of one size, share one
    #: raster shape): {"fshape": ..., "height": ..., "height2": ..., "support": ..., ("footprint", m): ...};
    #: filled by ncc_maps and vote_map. A kernel is used by one thread at a time (its class's task).
    spectra: dict = field(default_factory=dict, repr=False, compare=False)

    def _spectrum(self, c: Correlator, key, make):
        _, fshape = c._fshape(self.height.shape)
        if self.spectra.get("fshape") != fshape:
            self.spectra.clear()
            self.spectra["fshape"] = fshape
        if key not in self.spectra:
            self.spectra[key] = make()
        return self.spectra[key]

    def height_spectra(self, c: Correlator):
        """The spectra of `height` and `height`**2 for the correlator's padded shape (cached)."""
        return (self._spectrum(c, "height", lambda: c.kernel(self.height)),
                self._spectrum(c, "height2", lambda: c.kernel(self.height * self.height)))

    def support_spectrum(self, c: Correlator):
        """The spectrum of `support` for the correlator's padded shape (cached)."""
        return self._spectrum(c, "support", lambda: c.kernel(self.support))

    def footprint_cells(self, occupied_min_m: float) -> np.float64:
        """Cells of the footprint: where the top surface is higher than `occupied_min_m` (m). A NumPy
        float64, as the sum of the float footprint was: dividing a float32 map by it gives float64."""
        return (self.height > occupied_min_m).astype(np.float64).sum()

    def footprint_spectrum(self, c: Correlator, occupied_min_m: float):
        """The spectrum of the footprint (1 where the top surface is higher than `occupied_min_m`) for the
        correlator's padded shape (cached)."""
        return self._spectrum(c, ("footprint", float(occupied_min_m)),
                              lambda: c.kernel((self.height > occupied_min_m).astype(np.float64)))


def class_kernels(model, cell_m: float, yaw_step_deg: float) -> list[Kernel]:
    """Upright kernels of a class: one for continuous symmetry, else one per `yaw_step_deg` within a period."""
    if model.symmetric:
        yaws = [0.0]
    else:
        period = np.degrees(model.yaw_period_rad)
        yaws = np.deg2rad(np.arange(0.0, period - 1e-9, yaw_step_deg))
    out = []
    for yaw in yaws:
        h, c = model.top_height_map(cell_m, float(yaw), model.radius_m + 2 * cell_m)
        gx, gy = np.meshgrid(c, c)
        support = (np.hypot(gx, gy) <= model.radius_m + cell_m).astype(np.float64)
        out.append(Kernel(float(yaw), np.where(np.isfinite(h), h, 0.0) * support, support))
    return out


class Correlator:
    """Correlations ('same' size, float32: twice as fast as float64, and the sums involved are of a
    few thousand cells of heights below 10 m) of rasters of one shape with kernels, in the frequency
    domain.

    scipy's `signal.fftconvolve` transforms both inputs for every pair; the NCC correlates four rasters
    with a class's support and each kernel's two height maps with two rasters, so here each raster's
    and kernel's spectrum is computed once per padded shape and reused. The steps are fftconvolve's
    own (padding to `next_fast_len` of the full size, rfftn of float32 inputs, product, irfftn,
    centred crop), so every output equals fftconvolve's of the flipped kernel to the bit
    (tests/test_proposals_ncc.py). Not importing `scipy.signal` also spares every detection job the
    0.4 s that import costs.
    """

    def __init__(self, r: Raster):
        self.r = r
        self.shape = tuple(int(n) for n in r.h.shape)
        self._spectra = {}
        self._rasters = {}

    def check(self, r: Raster) -> Correlator:
        """Self, after checking that it was made for raster `r` (its cached spectra are of r)."""
        if r is not self.r:
            raise ValueError("this Correlator was made for another raster: make one per raster")
        return self

    def rasters(self, occupied_min_m: float) -> dict:
        """The rasters correlated (`ncc_rasters`: 'd', 'f', 'occ', with 'ff' = f * f; 'vocc': `vote_map`'s
        occupancy), computed once per `occupied_min_m`."""
        key = float(occupied_min_m)
        if key not in self._rasters:
            d, f, occ = ncc_rasters(self.r, occupied_min_m)
            vocc = (np.nan_to_num(self.r.h, nan=0.0) > occupied_min_m).astype(np.float64)
            self._rasters[key] = {"d": d, "f": f, "ff": f * f, "occ": occ, "vocc": vocc}
        return self._rasters[key]

    def raster_spectrum(self, name: str, kshape, occupied_min_m: float):
        """The spectrum of raster `name` of `rasters(occupied_min_m)` for kernels of `kshape` (cached per
        padded shape). Several threads may ask at once: the first ones compute it, all get the same."""
        _, fshape = self._fshape(kshape)
        key = (name, fshape, float(occupied_min_m))
        if key not in self._spectra:
            a = self.rasters(occupied_min_m)[name]
            self._spectra[key] = sp_fft.rfftn(a.astype(np.float32, copy=False), fshape, axes=(0, 1))
        return self._spectra[key]

    def raster_spectra_needed(self, kshapes, votes: bool) -> list:
        """The (raster name, kernel shape) pairs whose `raster_spectrum` `ncc_maps` (and `vote_map`, with
        `votes`) ask for kernels of `kshapes`: one kernel shape per distinct padded shape. Computing
        them first, in parallel, spares the classes' tasks from computing one twice."""
        shapes = {self._fshape(ks)[1]: ks for ks in kshapes}.values()
        names = ("d", "f", "ff", "occ") + (("vocc",) if votes else ())
        return [(name, ks) for name in names for ks in shapes]

    def _fshape(self, kshape) -> tuple[tuple[int, ...], tuple[int, ...]]:
        full = tuple(a + b - 1 for a, b in zip(self.shape, kshape))
        return full, tuple(sp_fft.next_fast_len(n, True) for n in full)

    def kernel(self, k: np.ndarray):
        """The spectrum of kernel `k`, flipped as a correlation needs."""
        _, fshape = self._fshape(k.shape)
        return sp_fft.rfftn(k[::-1, ::-1].astype(np.float32), fshape, axes=(0, 1))

    def corr(self, a_spec, k_spec, kshape) -> np.ndarray:
        """The correlation of a raster with a kernel of `kshape` from their spectra ('same' size)."""
        full, fshape = self._fshape(kshape)
        # The product is a temporary: the inverse transform may work in it instead of a copy.
        ret = sp_fft.irfftn(a_spec * k_spec, fshape, axes=(0, 1), overwrite_x=True)[: full[0], : full[1]]
        i0, j0 = (full[0] - self.shape[0]) // 2, (full[1] - self.shape[1]) // 2
        return ret[i0: i0 + self.shape[0], j0: j0 + self.shape[1]].copy()


def ncc_rasters(r: Raster, occupied_min_m: float):
    """The NCC's inputs: data mask (1 where a cell holds data), heights (m, 0 where none, negatives
    clipped) and occupancy (1 where higher than `occupied_min_m`), float64 rasters of r's shape."""
    d = np.isfinite(r.h).astype(np.float64)
    f = np.where(d > 0, np.clip(np.nan_to_num(r.h), 0.0, None), 0.0)
    return d, f, (f > occupied_min_m).astype(np.float64)


def ncc_maps(r: Raster, kernels: list[Kernel], occupied_min_m: float, min_data_frac: float,
             c: Correlator | None = None):
    """Masked normalised cross-correlation (Padfield 2012) of the height raster with each kernel.

    Cells without data (NaN: sonar shadow, or hidden under an accepted object) are left out of the sums;
    a cell's NCC counts (else -1) only where at least `min_data_frac` of the kernel's support holds data.
    Returns (best NCC per cell, index of the best kernel per cell, share of the support's cells with
    data that hold points above `occupied_min_m`). c: a `Correlator` of r shared with other calls on
    the same raster (the classes of a round: the raster spectra are computed once).
    """
    c = Correlator(r) if c is None else c.check(r)
    best = np.full(r.h.shape, -1.0)
    arg = np.zeros(r.h.shape, dtype=np.int64)
    occ_frac = None
    cache = {}
    for k, ker in enumerate(kernels):
        ks = ker.support.shape
        sd, sf_ = c.raster_spectrum("d", ks, occupied_min_m), c.raster_spectrum("f", ks, occupied_min_m)
        if ks not in cache:
            m = ker.support_spectrum(c)
            n = np.maximum(c.corr(sd, m, ks), 1.0)
            cache[ks] = (n, c.corr(sf_, m, ks), c.corr(c.raster_spectrum("ff", ks, occupied_min_m), m, ks),
                         c.corr(c.raster_spectrum("occ", ks, occupied_min_m), m, ks) / n)
        n, sf, sff, of = cache[ks]
        occ_frac = of
        t_spec, tt_spec = ker.height_spectra(c)
        st, stt, sft = c.corr(sd, t_spec, ks), c.corr(sd, tt_spec, ks), c.corr(sf_, t_spec, ks)
        _ncc_best(n, sf, sff, st, stt, sft, n >= min_data_frac * ker.support.sum(), k, best, arg)
    return best, arg, occ_frac


@numba.njit(cache=True, nogil=True)
def _ncc_best(n, sf, sff, st, stt, sft, ok, k, best, arg):
    """One kernel's NCC from its correlation sums (float32 maps, as the FFTs give them) and where it
    beats `best`, the best so far (float64), `best` and `arg` (= k) updated in place: one compiled
    pass of the NumPy expressions

        num = sft - sf * st / n
        den = sqrt(clip((sff - sf * sf / n) * (stt - st * st / n), 1e-12, None))
        ncc = where(ok, num / den, -1);  better = ncc > best

    in float32 as NumPy evaluates them (`tests/test_proposals_ncc.py` compares with them to the bit),
    without their nine temporary maps of the raster's size."""
    eps = np.float32(1e-12)
    m1 = np.float32(-1.0)
    for i in range(n.shape[0]):
        for j in range(n.shape[1]):
            if ok[i, j]:
                nn, a, b = n[i, j], sf[i, j], st[i, j]
                v = (sff[i, j] - a * a / nn) * (stt[i, j] - b * b / nn)
                if v < eps:  # NaN stays NaN, as in np.clip
                    v = eps
                ncc = (sft[i, j] - a * b / nn) / np.sqrt(v)
            else:
                ncc = m1
            if np.float64(ncc) > best[i, j]:
                best[i, j] = np.float64(ncc)
                arg[i, j] = k


def ncc_peaks(best: np.ndarray, occ_frac: np.ndarray, ncc_min: float, occ_min: float, nms_radius_cells: int):
    """Row/column indices of local maxima of `best` within `nms_radius_cells` that pass both minima,
    best first: the cells where best >= its (2 r + 1)^2 neighbourhood's maximum (r = the radius, at
    least 1; -1 beyond the raster, as ``ndi.maximum_filter(best, 2 r + 1, mode="constant", cval=-1)``),
    best >= ncc_min and occ_frac >= occ_min. The neighbourhood is looked at only around the cells that
    pass the minima (`_local_maxima`), usually a small share of the raster."""
    r = max(1, int(nms_radius_cells))
    cand = (best >= ncc_min) & (occ_frac >= occ_min)
    i, j = np.nonzero(cand)
    keep = _local_maxima(np.ascontiguousarray(best, dtype=np.float64), i, j, r)
    i, j = i[keep], j[keep]
    order = np.argsort(-best[i, j], kind="stable")
    return i[order], j[order]


@numba.njit(cache=True, nogil=True)
def _local_maxima(best, ii, jj, r):
    """Boolean (K,): best[ii[k], jj[k]] is no less than any value of best within r cells (Chebyshev),
    nor than -1 when that square reaches beyond the raster (`ncc_peaks`' maximum filter, evaluated at
    these cells only)."""
    h, w = best.shape
    out = np.zeros(ii.shape[0], dtype=np.bool_)
    for k in range(ii.shape[0]):
        i, j = ii[k], jj[k]
        v = best[i, j]
        ok = True
        if i - r < 0 or j - r < 0 or i + r >= h or j + r >= w:
            ok = v >= -1.0
        a = max(i - r, 0)
        while ok and a <= min(i + r, h - 1):
            for b in range(max(j - r, 0), min(j + r, w - 1) + 1):
                if not v >= best[a, b]:
                    ok = False
                    break
            a += 1
        out[k] = ok
    return out


def sliding_windows(xy_min, xy_max, side_m: float, overlap: float) -> np.ndarray:
    """Square windows (K,4) [xmin, ymin, xmax, ymax] of side `side_m` (m) covering the rectangle, with
    `overlap` (0..1) between neighbours; the grid starts at xy_min (deterministic for a given cloud)."""
    step = side_m * (1.0 - overlap)
    if step <= 0:
        raise ValueError(f"window step must be > 0 (side {side_m} m, overlap {overlap})")
    xs = np.arange(xy_min[0], max(xy_min[0], xy_max[0] - side_m) + step - 1e-9, step)
    ys = np.arange(xy_min[1], max(xy_min[1], xy_max[1] - side_m) + step - 1e-9, step)
    gx, gy = np.meshgrid(xs, ys)
    lo = np.stack([gx.ravel(), gy.ravel()], 1)
    return np.hstack([lo, lo + side_m])


def window_counts(xy: np.ndarray, windows: np.ndarray, cell_m: float = 0.05) -> np.ndarray:
    """Points (K,2) per window (W,4), counted with an integral image of `cell_m` cells (windows snapped to cells)."""
    if len(xy) == 0 or len(windows) == 0:
        return np.zeros(len(windows), dtype=np.int64)
    x0, y0 = windows[:, 0].min(), windows[:, 1].min()
    nx = int(np.ceil((max(windows[:, 2].max(), xy[:, 0].max()) - x0) / cell_m)) + 2
    ny = int(np.ceil((max(windows[:, 3].max(), xy[:, 1].max()) - y0) / cell_m)) + 2
    j = np.clip(((xy[:, 0] - x0) / cell_m).astype(np.int64), 0, nx - 1)
    i = np.clip(((xy[:, 1] - y0) / cell_m).astype(np.int64), 0, ny - 1)
    grid = np.zeros((ny + 1, nx + 1), dtype=np.int64)
    np.add.at(grid, (i + 1, j + 1), 1)
    ii = grid.cumsum(0).cumsum(1)
    c = lambda v, o, n: np.clip(np.round((v - o) / cell_m).astype(np.int64), 0, n)  # noqa: E731
    j0, j1 = c(windows[:, 0], x0, nx), c(windows[:, 2], x0, nx)
    i0, i1 = c(windows[:, 1], y0, ny), c(windows[:, 3], y0, ny)
    return ii[i1, j1] - ii[i0, j1] - ii[i1, j0] + ii[i0, j0]


def clusters(xy: np.ndarray, cell_m: float, min_points: int):
    """Connected groups of points (K,2) on a BEV occupancy grid of `cell_m` (8-connected).

    Returns a list of index arrays, one per cluster of at least `min_points` points, largest first.
    """
    if len(xy) == 0:
        return []
    x0, y0 = np.floor(xy.min(0) / cell_m) * cell_m  # cell-aligned: a crop sees the same cells
    j = ((xy[:, 0] - x0) / cell_m).astype(np.int64)
    i = ((xy[:, 1] - y0) / cell_m).astype(np.int64)
    occ = np.zeros((i.max() + 1, j.max() + 1), dtype=bool)
    occ[i, j] = True
    lab, n = ndi.label(occ, structure=np.ones((3, 3), dtype=bool))
    pl = lab[i, j]
    order = np.argsort(pl, kind="stable")
    bounds = np.flatnonzero(np.r_[True, pl[order][1:] != pl[order][:-1], True])
    out = [order[bounds[k]:bounds[k + 1]] for k in range(len(bounds) - 1)]
    out = [o for o in out if len(o) >= min_points]
    out.sort(key=lambda o: (-len(o), int(o[0])))
    return out
