"""Tiled detection of large surveys: plan tiles, run a detector per tile, merge the results.

A survey far larger than an object (hundreds of metres of soundings, objects at most 2.7 m wide) is
cut into square-ish tiles. Every tile has

* a **core**: the tiles' cores partition the survey's x/y bounds exactly (no gap, no overlap);
* a **padded** rectangle: the core grown by `overlap_m` on every side; the detector of a tile sees
  the points of its padded rectangle only, so memory and time per tile are bounded by the tile.

Only tiles near data are planned (`plan_tiles` with `near`, the occupied cells of a coarse grid from
`sonardet.survey.extent`), and isolated far soundings (fliers) are dropped by default before the
bounds are taken (`survey_layout`): a stray sounding 100 km off neither widens the plan to millions
of tiles nor costs memory in proportion to the bounding box.

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

Parallel tiles (`detect_tiled` with ``jobs`` > 1): the tiles run in worker processes forked once per
call (``concurrent.futures.ProcessPoolExecutor`` with the "fork" start method). The points, their x
order and the detector are handed to the workers by the fork itself (a module-level table set before
the pool starts, read-only in the workers: copy-on-write pages, never pickled), and each task carries
only its `Tile`: the worker cuts its tile out by index and gets a copy of that tile's points only, so
peak memory is the cloud once plus one tile per worker. Each worker runs its numerical libraries on
one thread (`_one_thread_per_worker`), so ``jobs`` workers use ``jobs`` cores. Results are put back in
plan order before merging, so the detections are the same, in the same order, as with ``jobs`` = 1.

Frames and units: metres, in the frame of the points given (a local frame or a survey CRS such as
UTM: x east, y north); all arithmetic in float64, so UTM coordinates (5e5, 4e6) are exact to
nanometres. Tile ids are "t{ix:03d}_{iy:03d}" with ix counting along x (east) and iy along y (north).
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing
import os
import sys
import time
import warnings
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sonardet.determinism import THREAD_VARIABLES
from sonardet.progress import progress_bar
from sonardet.survey.extent import (
    FLIER_GAP_M,
    FLIER_MAX_POINTS,
    FLIERS_LISTED,
    CellStats,
    Fliers,
    find_fliers,
)

log = logging.getLogger(__name__)

#: Default largest tile side (m) of `sonardet detect` and of the workflow's survey jobs. Chosen on
#: benchmarks/survey.py (training-scene mosaic and cast survey, never the test split): 50 m tiles
#: detected the same objects as 40 m tiles (equal mAP and per-class AP on both surveys) in 12 % (cast,
#: lone objects) to 36-41 % (mosaic of reef arrangements) less time, peak memory 1.1-1.3 GB PSS at 2
#: workers; the 3 m overlap's smaller share of a larger tile explains part of it (README "Speed" has
#: the numbers and what is not traced).
DEFAULT_TILE_M = 50.0

__all__ = ["DEFAULT_TILE_M", "SurveyLayout", "Tile", "available_cores", "check_jobs", "detect_survey", "detect_tiled",
           "merge_tile_detections", "plan_tiles", "survey_layout", "tile_points"]


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


def _n_cells(lo: float, hi: float, tile_m: float) -> int:
    """Number of equal cores along one axis: n = ceil(extent / tile_m) (>= 1)."""
    return max(1, int(np.ceil((hi - lo) / tile_m - 1e-9)))


def _edge(lo: float, hi: float, n: int, i: int) -> float:
    """Border i (0..n) of the n equal cores over [lo, hi] (m): lo + (hi - lo) i / n, the ends exact."""
    if i <= 0:
        return lo
    if i >= n:
        return hi
    return float(lo + (hi - lo) * np.float64(i) / n)


def _check_plan(bounds_xy, tile_m, overlap_m, min_overlap_m) -> tuple[float, float, float, float]:
    """The bounds as 4 floats; raise ValueError for bad bounds or settings (see `plan_tiles`)."""
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
    return xmin, ymin, xmax, ymax


def _near_cells(rects: np.ndarray, lo: float, hi: float, n: int, overlap_m: float, axis: int) -> np.ndarray:
    """(K, 2) first and last core index along one axis whose padded range may meet each rectangle's
    range (a superset by at most one core on each side; `plan_tiles` tests exactly)."""
    a, b = rects[:, axis] - overlap_m, rects[:, axis + 2] + overlap_m
    scale = n / (hi - lo) if hi > lo else 0.0
    first = np.floor((a - lo) * scale).astype(np.int64) - 1
    last = np.floor((b - lo) * scale).astype(np.int64) + 1
    return np.clip(np.c_[first, last], 0, n - 1)


def _tiles_near(rects, box, nx: int, ny: int, overlap_m: float) -> list[tuple[int, int]]:
    """(iy, ix) of the tiles whose padded rectangle meets one of `rects` ((K, 4) m), sorted row by row."""
    xmin, ymin, xmax, ymax = box
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    rx, ry = _near_cells(rects, xmin, xmax, nx, overlap_m, 0), _near_cells(rects, ymin, ymax, ny, overlap_m, 1)
    found = set()
    for r, (x0, x1), (y0, y1) in zip(rects, rx, ry):
        for ix in range(int(x0), int(x1) + 1):
            if _edge(xmin, xmax, nx, ix) - overlap_m > r[2] or _edge(xmin, xmax, nx, ix + 1) + overlap_m < r[0]:
                continue
            for iy in range(int(y0), int(y1) + 1):
                if _edge(ymin, ymax, ny, iy) - overlap_m <= r[3] and _edge(ymin, ymax, ny, iy + 1) + overlap_m >= r[1]:
                    found.add((iy, ix))
    return sorted(found)


def plan_tiles(bounds_xy, tile_m: float = DEFAULT_TILE_M, overlap_m: float = 3.0,
               min_overlap_m: float | None = None, near=None) -> list[Tile]:
    """Cut the rectangle `bounds_xy` = (xmin, ymin, xmax, ymax) (m, float64, any frame incl. UTM)
    into tiles at most `tile_m` wide.

    Along each axis the extent is split into n = ceil(extent / tile_m) equal cores (so no sliver tile
    is left at the end); the cores partition the bounds exactly (neighbours share their border values
    bit for bit). padded = core grown by `overlap_m` on each side. `min_overlap_m` (m): the smallest
    overlap that keeps the ownership rule exact, i.e. the largest object footprint (width) to be
    detected; a smaller `overlap_m` raises ValueError. Tiles are ordered row by row (iy, then ix).

    `near`: None plans every tile of the bounds. Else (K, 4) rectangles [xmin, ymin, xmax, ymax] (m)
    holding the data (e.g. `sonardet.survey.extent.CellStats.rects`): only the tiles whose padded
    rectangle meets one of them are returned, with the same ids, cores and padding as in the full plan
    (nx, ny are the full plan's), so the work and memory follow the occupied area, not the bounding box.

    Raises ValueError for non-finite bounds, xmax < xmin or ymax < ymin, tile_m <= 0, a negative
    overlap_m or overlap_m < min_overlap_m.
    """
    box = _check_plan(bounds_xy, tile_m, overlap_m, min_overlap_m)
    xmin, ymin, xmax, ymax = box
    nx, ny = _n_cells(xmin, xmax, tile_m), _n_cells(ymin, ymax, tile_m)
    cells = [(iy, ix) for iy in range(ny) for ix in range(nx)] if near is None else \
        _tiles_near(near, box, nx, ny, overlap_m)
    tiles = []
    for iy, ix in cells:
        core = (_edge(xmin, xmax, nx, ix), _edge(ymin, ymax, ny, iy), _edge(xmin, xmax, nx, ix + 1),
                _edge(ymin, ymax, ny, iy + 1))
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


@dataclass
class SurveyLayout:
    """Where a detector runs on a survey held in memory (`survey_layout`): keep (int64 indices of the
    points used, ascending; None: all of them), fliers (`sonardet.survey.extent.Fliers`, None when there
    are none), bounds ((xmin, ymin, xmax, ymax) of the points used, m) and tiles (`plan_tiles` over
    those bounds, only near occupied cells)."""

    keep: np.ndarray | None
    fliers: Fliers | None
    bounds: tuple[float, float, float, float]
    tiles: list[Tile]

    def points(self, xyz: np.ndarray) -> np.ndarray:
        """The points used (a copy when fliers were dropped)."""
        return xyz if self.keep is None else xyz[self.keep]


def survey_layout(xyz: np.ndarray, tile_m: float = DEFAULT_TILE_M, overlap_m: float = 3.0,
                  min_overlap_m: float | None = None, keep_fliers: bool = False, flier_gap_m: float = FLIER_GAP_M,
                  flier_max_points: int = FLIER_MAX_POINTS, source: str = "survey") -> SurveyLayout:
    """Fliers and tiles of the points xyz ((N, 3) float64 m, any frame incl. UTM; N >= 1).

    The occupied cells of a grid of `tile_m` (`sonardet.survey.extent.CellStats`) give the fliers
    (`find_fliers`: clusters of at most `flier_max_points` soundings more than `flier_gap_m` m from the
    rest), which are dropped unless `keep_fliers`, and logged (WARNING: count and coordinates, naming
    `source`) either way; then `plan_tiles` over the bounds of the points used, only near the occupied
    cells. Memory: the points' cell keys (16 bytes per point) and the occupied cells, whatever the
    bounding box. Settings are checked as in `plan_tiles` (ValueError)."""
    _check_plan((0.0, 0.0, 0.0, 0.0), tile_m, overlap_m, min_overlap_m)
    cells = CellStats.of(xyz, tile_m)
    is_flier = find_fliers(cells, flier_gap_m, flier_max_points)
    keep, fliers = None, None
    if is_flier.any():
        fliers = Fliers(cells.select(is_flier), flier_gap_m, flier_max_points, kept=keep_fliers)
        mask = fliers.cells.contains(xyz)
        fliers.points = np.asarray(xyz)[np.flatnonzero(mask)[:FLIERS_LISTED]]
        log.warning("%s", fliers.describe(source))
        if not keep_fliers:
            keep = np.flatnonzero(~mask)
            cells = cells.select(~is_flier)
    lo, hi = cells.bounds()
    bounds = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    return SurveyLayout(keep, fliers, bounds, plan_tiles(bounds, tile_m, overlap_m, min_overlap_m, near=cells.rects()))


def _column_index(xyz: np.ndarray, keep: np.ndarray | None):
    """Points (those of `keep`, else all) sorted by x once: their indices into xyz and their sorted x, so a
    tile's column is found by bisection."""
    if keep is None:
        order = np.argsort(xyz[:, 0], kind="stable")
    else:
        order = keep[np.argsort(xyz[keep, 0], kind="stable")]
    return order, xyz[order, 0]


def _cut_tile(p: np.ndarray, order: np.ndarray, xs: np.ndarray, tile: Tile) -> np.ndarray:
    """Indices (ascending) of the points of the tile's padded rectangle: its column strip by bisection in the
    x-sorted index (`_column_index`), then a test on y."""
    x0, y0, x1, y1 = tile.padded
    a, b = np.searchsorted(xs, x0, "left"), np.searchsorted(xs, x1, "right")
    col = order[a:b]
    yc = p[col, 1]
    return np.sort(col[(yc >= y0) & (yc <= y1)])


def _tile_row(tile: Tile, n_points: int) -> dict:
    """The per-tile row of `detect_tiled`, before the detector ran."""
    return {"tile": tile.id, "core": list(tile.core), "padded": list(tile.padded), "n_points": int(n_points),
            "n_detections": 0, "n_kept": 0, "seconds": 0.0, "skipped": n_points == 0, "stats": None}


def _run_tile(p: np.ndarray, idx: np.ndarray, tile: Tile, detect_fn: Callable, row: dict) -> list:
    """detect_fn on the tile's points p[idx]; fills the row's seconds, stats, counts; returns the detections."""
    t = time.perf_counter()
    res = detect_fn(p[idx])
    row["seconds"] = time.perf_counter() - t
    if isinstance(res, tuple) and len(res) == 2 and isinstance(res[1], dict):
        dets, row["stats"] = list(res[0]), res[1]
    else:
        dets = list(res)
    row["n_detections"] = len(dets)
    row["n_kept"] = sum(bool(tile.owns(d["box"][0], d["box"][1])) for d in dets)
    return dets


def _log_tile(k: int, n: int, tile: Tile, row: dict) -> None:
    if row["skipped"]:
        log.info("tile %d/%d %s: no points, skipped", k, n, tile.id)
    else:
        log.info("tile %d/%d %s: %d points, %d detections (%d centred in the core), %.1f s",
                 k, n, tile.id, row["n_points"], row["n_detections"], row["n_kept"], row["seconds"])


def available_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one, e.g. under
    ``taskset`` or a SLURM allocation; else ``os.cpu_count()``); at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def check_jobs(jobs) -> int:
    """`jobs` as an int; ValueError unless it is a whole number >= 1."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise ValueError(f"jobs must be a whole number >= 1 (tiles detected in parallel processes), got {jobs!r}")
    return int(jobs)


def _n_workers(jobs: int, n_tiles: int) -> int:
    """Worker processes `detect_tiled` starts for `jobs` and `n_tiles` tiles: at most one per tile; 1 (no
    worker: tiles in this process) where the platform cannot fork, this process has started CUDA or Numba's
    OpenMP threading layer (GNU OpenMP's threads do not survive a fork; Numba aborts the child)."""
    n = min(check_jobs(jobs), n_tiles)
    if n > 1 and "fork" not in multiprocessing.get_all_start_methods():
        log.warning("jobs = %d: this platform cannot fork worker processes; the tiles run one after another", n)
        return 1
    torch = sys.modules.get("torch")
    if n > 1 and torch is not None and torch.cuda.is_initialized():
        log.info("jobs = %d: the detector runs on a GPU, which forked processes cannot use; the tiles run one "
                 "after another on it", n)
        return 1
    if n > 1 and _numba_layer() == "omp":
        log.warning("jobs = %d: Numba's OpenMP threading layer is already running in this process, and a forked "
                    "process that runs Numba's parallel code aborts; the tiles run one after another (set "
                    "NUMBA_THREADING_LAYER=workqueue, or detect before any parallel Numba code runs)", n)
        return 1
    return max(n, 1)


def _numba_layer() -> str | None:
    """The threading layer Numba has started in this process ('omp', 'tbb', 'workqueue'), None if none."""
    numba = sys.modules.get("numba")
    if numba is None:
        return None
    try:
        return numba.threading_layer()
    except ValueError:  # not started yet
        return None


#: What the forked tile workers read: call token -> (points, x order, sorted x, detector). Set by
#: `_detect_parallel` before its pool forks, so the workers inherit it (nothing of it is pickled).
_FORKED: dict[int, tuple] = {}
_TOKENS = itertools.count()
#: threadpoolctl's limits of a worker (kept referenced for the worker's lifetime).
_WORKER_LIMITS: list = []


def _one_thread_per_worker() -> None:
    """Initializer of a tile worker: one thread for each numerical library, so `jobs` workers load `jobs`
    cores. Libraries loaded later in the worker read the thread variables; those the parent had loaded
    are set through their own calls (threadpoolctl for BLAS/OpenMP when installed; PyTorch, Numba,
    Open3D and the model-based detector's worker threads directly), since the variables are read only
    when a library loads."""
    for name in THREAD_VARIABLES:
        os.environ[name] = "1"
    if "numba" not in sys.modules:  # Numba refuses a NUMBA_NUM_THREADS changed after it was imported
        os.environ["NUMBA_NUM_THREADS"] = "1"
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        pass
    else:
        _WORKER_LIMITS.append(threadpool_limits(limits=1))
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)
    numba = sys.modules.get("numba")
    if numba is not None:
        try:
            numba.set_num_threads(1)
        except Exception as exc:  # no threading layer: numba's parallel code then runs on one thread anyway
            log.debug("numba.set_num_threads(1) in a tile worker: %s", exc)
    o3d = sys.modules.get("open3d")
    if o3d is not None and hasattr(o3d.utility, "set_max_threads"):
        o3d.utility.set_max_threads(1)
    tasks = sys.modules.get("sonardet.detect.model_based.tasks")
    if tasks is not None:  # the model-based detector's worker threads
        tasks.limit_threads(1)


def _tile_job(token: int, tile: Tile):
    """One tile in a worker: cut its points from the inherited cloud, run the detector; (detections, row)."""
    p, order, xs, detect_fn = _FORKED[token]
    idx = _cut_tile(p, order, xs, tile)
    row = _tile_row(tile, len(idx))
    dets = _run_tile(p, idx, tile, detect_fn, row) if len(idx) else None
    return dets, row


def _tile_failed(tile: Tile, exc: BaseException) -> Exception:
    """The error raised for a tile whose worker failed: names the tile and its core, keeps ValueError (a
    readable error of the command line) a ValueError."""
    x0, y0, x1, y1 = tile.core
    where = f"tile {tile.id} (core x {x0:.2f}..{x1:.2f} m, y {y0:.2f}..{y1:.2f} m)"
    if isinstance(exc, BrokenProcessPool):
        return RuntimeError(f"{where}: a tile worker process died unexpectedly (killed for lack of memory? "
                            f"try fewer jobs): {exc}")
    kind = ValueError if isinstance(exc, ValueError) else RuntimeError
    return kind(f"{where}: the detector failed: {type(exc).__name__}: {exc}")


def _detect_parallel(p, order, xs, tiles, detect_fn, workers: int, progress: bool, bar: bool):
    """`detect_tiled`'s loop over the tiles in `workers` forked processes: (per-tile detections, rows), both
    in plan order; the bar advances and the log lines come as tiles finish."""
    token = next(_TOKENS)
    _FORKED[token] = (p, order, xs, detect_fn)
    results = [None] * len(tiles)
    try:
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                                   initializer=_one_thread_per_worker)
        with pool, progress_bar(total=len(tiles), desc="detect", unit="tile", enabled=bar) as pbar:
            with warnings.catch_warnings():  # Python >= 3.12 warns on any fork of a process with threads (a lock
                # held by another thread stays held in the child); the forking is deliberate, see the module doc
                warnings.filterwarnings("ignore", message=r".*use of fork\(\) may lead to deadlocks",
                                        category=DeprecationWarning)
                pending = {pool.submit(_tile_job, token, tile): k for k, tile in enumerate(tiles)}
            while pending:
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for fut in sorted(done, key=pending.get):
                    k = pending.pop(fut)
                    if fut.exception() is not None:
                        pool.shutdown(wait=False, cancel_futures=True)
                        raise _tile_failed(tiles[k], fut.exception()) from fut.exception()
                    results[k] = fut.result()
                    pbar.update(1)
                    if progress:
                        _log_tile(k + 1, len(tiles), tiles[k], results[k][1])
    finally:
        del _FORKED[token]
    per_tile = {t.id: dets for t, (dets, _) in zip(tiles, results) if dets is not None}
    return per_tile, [row for _, row in results]


def detect_tiled(xyz: np.ndarray, detect_fn: Callable, tile_m: float = DEFAULT_TILE_M, overlap_m: float = 3.0,
                 progress: bool = True, min_overlap_m: float | None = None, dup_dist_m: float = 0.5,
                 keep_fliers: bool = False, layout: SurveyLayout | None = None, bar: bool = False, jobs: int = 1):
    """Run `detect_fn` tile by tile over the points xyz (N,3) (float64 metres, any frame incl. UTM)
    and merge the results.

    detect_fn(points (M,3) float64, the tile's padded subset in xyz's frame and in xyz's order) returns
    a list of detections (boxes in the same frame), or (detections, stats dict). Tiles come from
    `survey_layout` (or the `layout` given): fliers dropped (unless `keep_fliers`) and logged, tiles
    over the bounds of the points used but only near occupied cells; tiles whose padded rectangle
    holds no point are skipped. Memory: the points are sorted by x once (an index and one column, 16
    bytes per point); a tile's column strip is found by bisection (its indices and y values, 16 bytes
    per point of the strip, live while the tile is cut out) and the detector gets a copy of the tile's
    points only, never of the whole cloud. With `progress`, every tile is logged at INFO level ("tile
    3/9 t002_000: 51234 points, 2 detections, 4.1 s"); with `bar`, a
    progress bar with the time left is drawn on a terminal (`sonardet.progress`).

    jobs: tiles detected at once, each in a worker process forked for this call (at most one per tile;
    see the module doc: the workers inherit the points and the detector, cut their tile by index and
    run their libraries on one thread). The detections and rows are those of ``jobs`` = 1 (the rows'
    seconds aside), in the same order, provided the detector's results do not depend on its thread count
    (the project's detectors: model-based runs Open3D on one thread, SASA on ``num_threads``, default 1;
    a multi-threaded reduction may round differently from the workers' single thread). Tiles are logged
    and the bar advances as they finish. A
    detector's exception in a worker is raised here as a RuntimeError (ValueError for a ValueError)
    naming the tile, chained to the original. ``jobs`` = 1 runs every tile in this process.

    Returns (detections, per_tile_stats): the merged detections (`merge_tile_detections`, sorted by
    descending score) and one dict per planned tile {tile, core, padded, n_points, n_detections, n_kept,
    seconds, skipped, stats (what detect_fn returned, if any)}.
    """
    p = np.asarray(xyz)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"xyz must be an (N,3) array of x, y, z in metres, got shape {p.shape}")
    check_jobs(jobs)
    if len(p) == 0:
        _check_plan((0.0, 0.0, 0.0, 0.0), tile_m, overlap_m, min_overlap_m)
        return [], []
    layout = layout or survey_layout(p, tile_m, overlap_m, min_overlap_m, keep_fliers)
    tiles = layout.tiles
    order, xs = _column_index(p, layout.keep)
    workers = _n_workers(jobs, len(tiles))
    if workers > 1:
        per_tile, rows = _detect_parallel(p, order, xs, tiles, detect_fn, workers, progress, bar)
        return merge_tile_detections(per_tile, tiles, dup_dist_m), rows
    per_tile, rows = {}, []
    for k, tile in enumerate(progress_bar(tiles, desc="detect", unit="tile", enabled=bar), 1):
        idx = _cut_tile(p, order, xs, tile)
        row = _tile_row(tile, len(idx))
        rows.append(row)
        if len(idx):
            per_tile[tile.id] = _run_tile(p, idx, tile, detect_fn, row)
        if progress:
            _log_tile(k, len(tiles), tile, row)
    return merge_tile_detections(per_tile, tiles, dup_dist_m), rows


def detect_survey(xyz: np.ndarray, detect_fn: Callable, tile_m: float = DEFAULT_TILE_M, overlap_m: float = 3.0,
                  min_overlap_m: float | None = None, keep_fliers: bool = False, source: str = "survey",
                  bar: bool = False, jobs: int = 1):
    """Detection on a whole survey held in memory (what ``sonardet detect`` runs): `survey_layout`
    (fliers dropped unless `keep_fliers`, logged naming `source`), then `detect_fn` on the points used in
    one call when one tile covers them, else `detect_tiled` (with `bar`, a progress bar on a terminal;
    `jobs` tiles at once in worker processes). xyz: (N, 3) float64 m, any frame.

    Returns (detections, info): detections in xyz's frame; info {n_points (used), n_tiles (tiles that
    held points), jobs (worker processes used; 1: all in this process), rows (`detect_tiled`'s per-tile
    rows, None for one tile), fliers (the `Fliers.to_json` report, None without fliers)}."""
    p = np.asarray(xyz)
    if p.ndim != 2 or p.shape[1] != 3 or not len(p):
        raise ValueError(f"{source}: expected (N, 3) points with N >= 1, got shape {p.shape}")
    check_jobs(jobs)
    layout = survey_layout(p, tile_m, overlap_m, min_overlap_m, keep_fliers, source=source)
    info = {"n_points": len(p) if layout.keep is None else len(layout.keep), "n_tiles": 1, "jobs": 1, "rows": None,
            "fliers": layout.fliers.to_json() if layout.fliers is not None else None}
    if len(layout.tiles) == 1:
        res = detect_fn(layout.points(p))
        dets = list(res[0]) if isinstance(res, tuple) and len(res) == 2 and isinstance(res[1], dict) else list(res)
        return dets, info
    b = layout.bounds
    info["jobs"] = _n_workers(jobs, len(layout.tiles))
    log.info("%s: %d points over %.1f x %.1f m in %d tiles of <= %g m (overlap %g m)%s", source, info["n_points"],
             b[2] - b[0], b[3] - b[1], len(layout.tiles), tile_m, overlap_m,
             f", {info['jobs']} at once" if info["jobs"] > 1 else "")
    dets, rows = detect_tiled(p, detect_fn, tile_m, overlap_m, True, min_overlap_m, layout=layout, bar=bar,
                              jobs=info["jobs"])
    info.update(rows=rows, n_tiles=sum(not r["skipped"] for r in rows))
    return dets, info
