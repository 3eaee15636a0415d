"""Where a survey's soundings are: occupied cells of a coarse grid, and isolated far soundings (fliers).

A survey file's bounding box says little about where its data are: one sounding 100 km off (a GPS
glitch, a bad line in an export) makes a 40 m survey's box 100 km wide, and tiles planned over that box
number millions. Here the data are summarised by the cells of a coarse grid that hold soundings
(:class:`CellStats`: per cell the count and the x, y, z range; memory grows with the occupied cells,
never with the box), which can be built chunk by chunk and merged (:meth:`CellStats.merge`).

Fliers (:func:`find_fliers`): the occupied cells are grouped into clusters, two cells belonging to
one cluster when their gap is at most `gap_m` (default :data:`FLIER_GAP_M`, 100 m). A cluster other
than the largest that holds at most `max_points` soundings (default :data:`FLIER_MAX_POINTS`) is a
group of fliers: a few soundings more than `gap_m` from any other data. They are dropped by default
and reported (count and coordinates); a caller may keep them (`keep_fliers`), and the tiles then
cover each cluster, never the empty space between them (`sonardet.survey.tiling.plan_tiles` with
`near`).

Frames and units: metres, in the survey's own coordinates (its CRS), float64. Cells are aligned to
multiples of `cell_m` (cell (i, j) covers [i cell_m, (i+1) cell_m) x [j cell_m, (j+1) cell_m)), so
chunks of one survey agree on them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

log = logging.getLogger(__name__)

__all__ = ["FLIER_GAP_M", "FLIER_MAX_POINTS", "CellStats", "Fliers", "cell_keys", "find_fliers"]

#: Soundings farther than this (m) from any other data are candidates for fliers.
FLIER_GAP_M = 100.0
#: A far cluster of at most this many soundings is a group of fliers (a real patch of seabed holds
#: thousands per 10 m x 10 m).
FLIER_MAX_POINTS = 100
#: At most this many flier coordinates are listed in messages and reports.
FLIERS_LISTED = 10


def cell_keys(xy: np.ndarray, cell_m: float) -> np.ndarray:
    """Cell index (i, j) (int64 (N, 2)) of each position (x, y) (m) on the grid of `cell_m` aligned to
    multiples of `cell_m`."""
    return np.floor(np.asarray(xy, dtype=np.float64)[:, :2] / float(cell_m)).astype(np.int64)


@dataclass
class CellStats:
    """Occupied cells of a coarse grid (see the module doc): keys (K, 2) int64 cell indices, in
    lexicographic order; count (K,) soundings per cell; lo, hi (K, 3) float64 the smallest and largest
    x, y, z (m) of the soundings in each cell."""

    cell_m: float
    keys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    count: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    lo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    hi: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @classmethod
    def of(cls, xyz: np.ndarray, cell_m: float) -> CellStats:
        """The occupied cells of points xyz ((N, 3), m); memory: the points' cell keys (16 bytes per
        point) while this runs, then the occupied cells only."""
        xyz = np.asarray(xyz, dtype=np.float64)
        if not len(xyz):
            return cls(float(cell_m))
        keys, inv = np.unique(cell_keys(xyz, cell_m), axis=0, return_inverse=True)
        inv = inv.ravel()
        return cls._reduce(float(cell_m), keys, inv, np.ones(len(xyz), np.int64), xyz, xyz)

    @classmethod
    def _reduce(cls, cell_m, keys, inv, count, lo, hi) -> CellStats:
        k = len(keys)
        c = np.bincount(inv, weights=count, minlength=k).astype(np.int64)
        out_lo = np.full((k, 3), np.inf)
        out_hi = np.full((k, 3), -np.inf)
        np.minimum.at(out_lo, inv, lo)
        np.maximum.at(out_hi, inv, hi)
        return cls(cell_m, keys, c, out_lo, out_hi)

    def merge(self, other: CellStats) -> CellStats:
        """The cells of both (counts added, ranges joined); both on the same grid."""
        if other.cell_m != self.cell_m:
            raise ValueError(f"cells of {self.cell_m} m and {other.cell_m} m cannot be merged")
        keys, inv = np.unique(np.vstack([self.keys, other.keys]), axis=0, return_inverse=True)
        return CellStats._reduce(self.cell_m, keys, inv.ravel(), np.r_[self.count, other.count],
                                 np.vstack([self.lo, other.lo]), np.vstack([self.hi, other.hi]))

    def select(self, mask: np.ndarray) -> CellStats:
        """The cells where `mask` ((K,) bool) is true."""
        return CellStats(self.cell_m, self.keys[mask], self.count[mask], self.lo[mask], self.hi[mask])

    @property
    def n_points(self) -> int:
        """Soundings in these cells."""
        return int(self.count.sum())

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) x, y, z (m) of the soundings in these cells."""
        return self.lo.min(0), self.hi.max(0)

    def rects(self) -> np.ndarray:
        """(K, 4) [xmin, ymin, xmax, ymax] (m) of the soundings in each cell."""
        return np.c_[self.lo[:, :2], self.hi[:, :2]]

    def contains(self, xyz: np.ndarray) -> np.ndarray:
        """Whether each point ((N, 3), m) lies in one of these cells."""
        if not len(self.keys) or not len(xyz):
            return np.zeros(len(xyz), dtype=bool)
        k = cell_keys(xyz, self.cell_m)
        # Lexicographic search of (i, j) among the sorted keys.
        keys = np.ascontiguousarray(self.keys).view([("i", np.int64), ("j", np.int64)]).ravel()
        q = np.ascontiguousarray(k).view([("i", np.int64), ("j", np.int64)]).ravel()
        pos = np.clip(np.searchsorted(keys, q), 0, len(keys) - 1)
        return keys[pos] == q


@dataclass
class Fliers:
    """The fliers of a survey: cells (the :class:`CellStats` of the flier clusters), gap_m and max_points
    (the rule that found them), kept (whether they stay in the data), points (up to
    :data:`FLIERS_LISTED` of their coordinates (m), filled by the caller that holds the points)."""

    cells: CellStats
    gap_m: float
    max_points: int
    kept: bool = False
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    @property
    def n_points(self) -> int:
        """Number of flier soundings."""
        return self.cells.n_points

    def describe(self, source: str) -> str:
        """One line for the log: how many fliers, where, and what was done with them."""
        pts = "; ".join("(" + ", ".join(f"{v:.3f}" for v in p) + ")" for p in self.points[:FLIERS_LISTED])
        more = f" and {self.n_points - len(self.points[:FLIERS_LISTED])} more" if self.n_points > FLIERS_LISTED else ""
        what = "kept (keep_fliers; they get tiles of their own)" if self.kept else \
            "dropped (keep them with keep_fliers / --keep-fliers)"
        return (f"{source}: {self.n_points} isolated sounding(s) more than {self.gap_m:g} m from the rest of the data "
                f"(clusters of at most {self.max_points} soundings), {what}: x, y, z = {pts or '-'}{more}")

    def to_json(self) -> dict:
        """The report of the fliers for a JSON document (tile index, summaries); coordinates in m."""
        return {"n_points": self.n_points, "kept": self.kept, "gap_m": self.gap_m, "max_points": self.max_points,
                "points": [[float(v) for v in p] for p in self.points[:FLIERS_LISTED]]}


def find_fliers(cells: CellStats, gap_m: float = FLIER_GAP_M, max_points: int = FLIER_MAX_POINTS) -> np.ndarray:
    """Which occupied cells ((K,) bool) hold fliers: cells of a cluster (cells linked when the gap
    between their soundings' x/y ranges is at most `gap_m` m, Chebyshev) that is not the largest
    cluster by soundings and holds at most `max_points` soundings. Cost: a k-d tree over the occupied
    cells."""
    k = len(cells.keys)
    if k <= 1:
        return np.zeros(k, dtype=bool)
    rects = cells.rects()
    centre, half = 0.5 * (rects[:, :2] + rects[:, 2:]), 0.5 * (rects[:, 2:] - rects[:, :2])
    # Candidate pairs by cell centres (a cell's soundings lie within one cell of its centre), then the
    # exact gap between the soundings' ranges.
    pairs = cKDTree(centre).query_pairs(gap_m + 2.0 * cells.cell_m, p=np.inf, output_type="ndarray")
    if len(pairs):
        gap = np.abs(centre[pairs[:, 0]] - centre[pairs[:, 1]]) - half[pairs[:, 0]] - half[pairs[:, 1]]
        pairs = pairs[(gap.max(axis=1) <= gap_m)]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(k, k)) if len(pairs) else \
        coo_matrix((k, k))
    n, label = connected_components(graph, directed=False)
    if n == 1:
        return np.zeros(k, dtype=bool)
    size = np.bincount(label, weights=cells.count, minlength=n)
    flier_cluster = size <= max_points
    flier_cluster[int(np.argmax(size))] = False  # the survey itself, however small
    return flier_cluster[label]
