"""Tiled detection of large surveys: plan tiles, run a detector per tile, merge the results.

A survey far larger than an object (hundreds of metres of soundings, objects at most 2.7 m wide) is
cut into square-ish tiles. Every tile has

* a **core**: the tiles' cores partition the survey's x/y bounds exactly (no gap, no overlap);
* a **padded** rectangle: the core grown by `overlap_m` on every side; the detector of a tile sees
  the points of its padded rectangle only, so memory and time per tile are bounded by the tile.

Ownership rule (`merge_tile_detections`): a tile reports only the detections whose box centre lies
in its core. Why that is enough: an object's points lie within its horizontal footprint, so they are
no farther than the footprint (<= the largest object's width) from its box centre. When
`overlap_m` is at least that footprint, the padded rectangle of the tile whose core holds the
centre holds every point of the object, plus a margin of context around it: that tile sees the
object whole and reports it, and every other tile that sees part of it drops its (possibly partial)
fit because the fitted centre lies outside its own core. Each object is thus reported by exactly
one tile. As a safety net for fits whose centres straddle a seam (the same object fitted a few
millimetres to each side of the core border by two tiles), detections of *different* tiles whose box
centres are closer than `dup_dist_m` are suppressed, the higher score kept.

Frames and units: metres, in the frame of the points given (a local frame or a survey CRS such as
UTM: x east, y north); all arithmetic in float64, so UTM coordinates (5e5, 4e6) are exact to
nanometres. Tile ids are "t{ix:03d}_{iy:03d}" with ix counting along x (east) and iy along y (north).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sonardet.progress import progress_bar

log = logging.getLogger(__name__)

__all__ = ["Tile", "detect_tiled", "merge_tile_detections", "plan_tiles", "tile_points"]


@dataclass(frozen=True)
class Tile:
    """One tile of a survey (metres, in the survey's frame).

    id: "t{ix:03d}_{iy:03d}"; ix, iy: column (along x) and row (along y) index; nx, ny: the numbers
    of columns and rows of the plan. core: (xmin, ymin, xmax, ymax) of the core rectangle; padded:
    the core grown by the overlap on every side (the region whose points the tile's detector sees).
    """

    id: str
    ix: int
    iy: int
    nx: int
    ny: int
    core: tuple[float, float, float, float]
    padded: tuple[float, float, float, float]

    def in_core(self, x, y) -> np.ndarray:
        """Whether positions (x, y) (m, arrays of one shape or scalars) lie in this tile's core.

        Cores are half-open, [xmin, xmax) x [ymin, ymax), except that the last column and row also
        hold their upper border, so every position of the survey bounds lies in exactly one core.
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        x0, y0, x1, y1 = self.core
        inx = (x >= x0) & ((x < x1) | ((self.ix == self.nx - 1) & (x <= x1)))
        iny = (y >= y0) & ((y < y1) | ((self.iy == self.ny - 1) & (y <= y1)))
        return inx & iny

    def owns(self, x, y) -> np.ndarray:
        """Whether this tile reports a detection whose box centre is at (x, y) (m).

        As `in_core`, but the border tiles' cores extend to infinity outwards: a partly scanned object
        at the survey edge may have its box centre just outside the points' bounds, and it still has
        to be reported by exactly one tile (the nearest). The ownership regions partition the plane.
        """
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        x0, y0, x1, y1 = self.core
        lo_x = (x >= x0) | (self.ix == 0)
        hi_x = (x < x1) | (self.ix == self.nx - 1)
        lo_y = (y >= y0) | (self.iy == 0)
        hi_y = (y < y1) | (self.iy == self.ny - 1)
        return lo_x & hi_x & lo_y & hi_y


def _edges(lo: float, hi: float, tile_m: float) -> np.ndarray:
    """Core borders along one axis: n = ceil(extent / tile_m) (>= 1) equal cells over [lo, hi]."""
    n = max(1, int(np.ceil((hi - lo) / tile_m - 1e-9)))
    e = lo + (hi - lo) * np.arange(n + 1, dtype=np.float64) / n
    e[0], e[-1] = lo, hi  # exact ends, whatever the rounding
    return e


def plan_tiles(bounds_xy, tile_m: float = 40.0, overlap_m: float = 3.0,
               min_overlap_m: float | None = None) -> list[Tile]:
    """Cut the rectangle `bounds_xy` = (xmin, ymin, xmax, ymax) (m, float64, any frame incl. UTM)
    into tiles at most `tile_m` wide.

    Along each axis the extent is split into n = ceil(extent / tile_m) equal cores (so no sliver tile
    is left at the end); the cores partition the bounds exactly (neighbours share their border values
    bit for bit). padded = core grown by `overlap_m` on each side. `min_overlap_m` (m): the smallest
    overlap that keeps the ownership rule exact, i.e. the largest object footprint (width) to be
    detected; a smaller `overlap_m` raises ValueError. Tiles are ordered row by row (iy, then ix).

    Raises ValueError for non-finite bounds, xmax < xmin or ymax < ymin, tile_m <= 0, a negative
    overlap_m or overlap_m < min_overlap_m.
    """
    b = np.asarray(bounds_xy, dtype=np.float64)
    if b.shape != (4,) or not np.all(np.isfinite(b)):
        raise ValueError(f"bounds_xy must be 4 finite numbers (xmin, ymin, xmax, ymax) in metres, got {bounds_xy!r}")
    xmin, ymin, xmax, ymax = (float(v) for v in b)
    if xmax < xmin or ymax < ymin:
        raise ValueError(f"bounds_xy must have xmin <= xmax and ymin <= ymax, got {bounds_xy!r}")
    if not (np.isfinite(tile_m) and tile_m > 0):
        raise ValueError(f"tile_m must be a positive number of metres, got {tile_m!r}")
    if not (np.isfinite(overlap_m) and overlap_m >= 0):
        raise ValueError(f"overlap_m must be a number of metres >= 0, got {overlap_m!r}")
    if min_overlap_m is not None and overlap_m < min_overlap_m:
        raise ValueError(
            f"overlap_m = {overlap_m:g} m is smaller than the largest object footprint ({min_overlap_m:g} m): an "
            f"object whose centre lies in a tile's core could then have points outside that tile's padded area "
            f"and be missed or cut; use overlap_m >= {min_overlap_m:g}")
    ex, ey = _edges(xmin, xmax, tile_m), _edges(ymin, ymax, tile_m)
    nx, ny = len(ex) - 1, len(ey) - 1
    tiles = []
    for iy in range(ny):
        for ix in range(nx):
            core = (float(ex[ix]), float(ey[iy]), float(ex[ix + 1]), float(ey[iy + 1]))
            padded = (core[0] - overlap_m, core[1] - overlap_m, core[2] + overlap_m, core[3] + overlap_m)
            tiles.append(Tile(f"t{ix:03d}_{iy:03d}", ix, iy, nx, ny, core, padded))
    return tiles


def tile_points(xyz: np.ndarray, tile: Tile) -> np.ndarray:
    """Indices (int64, ascending) of the points (N,3) (m, the tiles' frame) in the tile's padded
    rectangle (borders included). Builds one boolean mask of N, no copy of the points."""
    p = np.asarray(xyz)
    x0, y0, x1, y1 = tile.padded
    x, y = p[:, 0], p[:, 1]
    return np.flatnonzero((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1))


def _centre(det) -> np.ndarray:
    return np.asarray(det["box"][:3], dtype=np.float64)


def merge_tile_detections(per_tile: dict, tiles, dup_dist_m: float = 0.5) -> list[dict]:
    """Merge the detections of the tiles (dict tile id -> list of detections, boxes in the tiles'
    frame, metres) into one list sorted by descending score.

    1. A tile's detection is kept only if its box centre (x, y) lies in that tile's core (border
       tiles: extended outwards, `Tile.owns`); see the module doc for why this reports each object
       once when the overlap is at least the largest object's footprint.
    2. Safety net: among the kept detections of *different* tiles, one whose box centre (3-D) is
       closer than `dup_dist_m` (m) to a higher-scored one is dropped, whatever the classes. The
       detections of one tile are never suppressed against each other: the detector has already
       decided between them (two touching objects of a pile stay two).
    Ties in score keep the detection of the tile listed first in `tiles`. Unknown tile ids raise
    ValueError.
    """
    by_id = {t.id: t for t in tiles}
    order = {t.id: k for k, t in enumerate(tiles)}
    kept = []  # (score, tile order, index in tile, tile id, det)
    for tid, dets in per_tile.items():
        if tid not in by_id:
            raise ValueError(f"detections of unknown tile {tid!r}; tiles: {', '.join(sorted(by_id))}")
        tile = by_id[tid]
        for k, d in enumerate(dets):
            c = _centre(d)
            if bool(tile.owns(c[0], c[1])):
                kept.append((-float(d["score"]), order[tid], k, tid, d))
    kept.sort(key=lambda r: r[:3])
    out, centres, owners = [], [], []
    for _, _, _, tid, d in kept:
        c = _centre(d)
        if centres:
            dist = np.linalg.norm(np.asarray(centres) - c, axis=1)
            other = np.asarray(owners) != tid
            if np.any(other & (dist < dup_dist_m)):
                log.debug("tile %s: %s at %s duplicates a better detection of a neighbouring tile; dropped",
                          tid, d["cls"], np.round(c, 3).tolist())
                continue
        out.append(d)
        centres.append(c)
        owners.append(tid)
    return out


def _column_index(x: np.ndarray):
    """Points sorted by x once (indices and sorted x), so a tile's column is found by bisection."""
    order = np.argsort(x, kind="stable")
    return order, x[order]


def detect_tiled(xyz: np.ndarray, detect_fn: Callable, tile_m: float = 40.0, overlap_m: float = 3.0,
                 progress: bool = True, min_overlap_m: float | None = None, dup_dist_m: float = 0.5,
                 bar: bool = False):
    """Run `detect_fn` tile by tile over the points xyz (N,3) (float64 metres, any frame incl. UTM)
    and merge the results.

    detect_fn(points (M,3) float64, the tile's padded subset in xyz's frame and in xyz's order) returns
    a list of detections (boxes in the same frame), or (detections, stats dict). Tiles come from
    `plan_tiles` over the points' x/y bounds; tiles whose padded rectangle holds no point are skipped.
    Memory: the points are sorted by x once (an index and one column, 16 bytes per point); a tile's
    column strip is found by bisection (its indices and y values, 16 bytes per point of the strip,
    live while the tile is cut out) and the detector gets a copy of the tile's points only, never of
    the whole cloud. With `progress`, every tile is
    logged at INFO level ("tile 3/9 t002_000: 51234 points, 2 detections, 4.1 s"); with `bar`, a progress
    bar with the time left is drawn on a terminal (`sonardet.progress`).

    Returns (detections, per_tile_stats): the merged detections (`merge_tile_detections`, sorted by
    descending score) and one dict per tile {tile, core, padded, n_points, n_detections, n_kept,
    seconds, skipped, stats (what detect_fn returned, if any)}.
    """
    p = np.asarray(xyz)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"xyz must be an (N,3) array of x, y, z in metres, got shape {p.shape}")
    if len(p) == 0:
        return [], []
    lo, hi = p[:, :2].min(0), p[:, :2].max(0)
    tiles = plan_tiles((lo[0], lo[1], hi[0], hi[1]), tile_m, overlap_m, min_overlap_m)
    order, xs = _column_index(p[:, 0])
    per_tile, rows = {}, []
    for k, tile in enumerate(progress_bar(tiles, desc="detect", unit="tile", enabled=bar), 1):
        x0, y0, x1, y1 = tile.padded
        a, b = np.searchsorted(xs, x0, "left"), np.searchsorted(xs, x1, "right")
        col = order[a:b]
        yc = p[col, 1]
        idx = np.sort(col[(yc >= y0) & (yc <= y1)])
        row = {"tile": tile.id, "core": list(tile.core), "padded": list(tile.padded), "n_points": int(len(idx)),
               "n_detections": 0, "n_kept": 0, "seconds": 0.0, "skipped": len(idx) == 0, "stats": None}
        rows.append(row)
        if len(idx) == 0:
            if progress:
                log.info("tile %d/%d %s: no points, skipped", k, len(tiles), tile.id)
            continue
        t = time.perf_counter()
        res = detect_fn(p[idx])
        row["seconds"] = time.perf_counter() - t
        if isinstance(res, tuple) and len(res) == 2 and isinstance(res[1], dict):
            dets, row["stats"] = list(res[0]), res[1]
        else:
            dets = list(res)
        per_tile[tile.id] = dets
        row["n_detections"] = len(dets)
        row["n_kept"] = sum(bool(tile.owns(d["box"][0], d["box"][1])) for d in dets)
        if progress:
            log.info("tile %d/%d %s: %d points, %d detections (%d centred in the core), %.1f s",
                     k, len(tiles), tile.id, len(idx), len(dets), row["n_kept"], row["seconds"])
    return merge_tile_detections(per_tile, tiles, dup_dist_m), rows
