"""Cutting a survey file into tiles for one detection job per tile: the streaming split, the tile index
and the tiles' points.

The workflow (rules/survey.smk) runs the model-based detector on a survey file in three steps:

1. `split_survey` (checkpoint ``survey_tiles``): reads the survey in chunks, finds the occupied cells
   and the fliers (`sonardet.survey.extent`), plans the tiles over the x/y bounds of the points used,
   near the occupied cells only (`sonardet.survey.tiling.plan_tiles`, the plan `detect_tiled` and
   ``sonardet detect`` make) and writes the points of each tile's padded rectangle to
   ``tiles/{tile}.npz`` and the tile index JSON (`read_tile_index`, `tile_ids`).
2. one detection job per tile that holds points, on that tile's points only (`read_tile_points`), so
   its memory is bounded by the tile (peak RSS 264 MB for a 380 000-point 46 m x 46 m padded tile of
   bare seabed, against the whole survey held by ``sonardet detect``);
3. `sonardet.survey.merge.merge_survey_detections` merges them with `merge_tile_detections` (each
   object reported by the one tile owning its box centre, no duplicate or loss on the seams) and
   `write_survey_detections` writes JSON/CSV/GeoJSON in the survey's own coordinates.

A tile receives exactly the points, in the same order and with the same float64 values, that
`detect_tiled` hands its detector for that tile, so the workflow's merged detections equal those of
the one-process tiled path (``sonardet detect``).

Frames and units: metres. Everything here is in the survey file's own coordinates (its CRS, e.g.
UTM easting, northing, elevation), float64 throughout: tile points are stored as read (never
pre-shifted), tile rectangles and detections are in the same coordinates. The survey's local origin
(`sonardet.io.origin.choose_origin` of the bounds' minimum, whole metres, z = 0; or the origin the file
carries) is stored in the index and in each tile's NPZ (``origin`` entry), for code that needs local
coordinates (``local = xyz - origin``) before float32 work; the model-based detector shifts its input
itself.

Memory of the split (N survey points, C = ``chunk_points``, T = points of the largest padded tile):
text (``.xyz/.txt/.pts/.csv``, gzipped or not) and LAS/LAZ files are read C points at a time, so the
split holds one parsed chunk (the pandas parser's buffers and the chunk's x, y, z: roughly 150 bytes
per point of a chunk) plus one tile (24 x T bytes) while it writes that tile's NPZ, never the whole
survey. Measured on a 200 m x 200 m text survey of 7.2 million points (180 per m^2, 25 tiles of 40 m,
T = 381 000): peak RSS 215 MB with C = 1e6 and 112 MB with C = 2e5 (69 MB of it the interpreter and
imports), against 443 MB for reading the whole file with `read_points` as ``sonardet detect`` does. PLY
and NPZ files have no streaming reader (`sonardet.io.points.iter_chunks`): they are read whole (24 x N
bytes), then cut in chunks.
Disk: a spool of the survey's coordinates (24 x N bytes, deleted at the end) and the tiles, 24 bytes per
point and tile (uncompressed NPZ; 207 MB for the 7.2 million points above). Only x, y, z are kept in
the tiles; per-point attributes of the file are not read.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sonardet import SCHEMA_VERSION
from sonardet.io.artifacts import read_json_file
from sonardet.io.atomic import atomic_write_text
from sonardet.io.origin import choose_origin
from sonardet.io.points import (
    DEFAULT_CHUNK_POINTS,
    PointCloud,
    PointCloudError,
    format_module,
    read_points,
    write_points,
)
from sonardet.survey.extent import (
    FLIER_GAP_M,
    FLIER_MAX_POINTS,
    FLIERS_LISTED,
    CellStats,
    Fliers,
    find_fliers,
)
from sonardet.survey.source import SurveySource, survey_chunks
from sonardet.survey.tiling import DEFAULT_TILE_M, Tile, plan_tiles, tile_points

log = logging.getLogger(__name__)

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "SurveyReader",
    "open_survey",
    "read_tile_index",
    "read_tile_points",
    "split_survey",
    "tile_ids",
]


# --------------------------------------------------------------------------------- chunked reading
@dataclass
class SurveyReader:
    """A survey file opened for chunked reading (see `open_survey`).

    path: the file. format: 'text', 'las', 'ply' or 'npz'. crs: the CRS of the coordinates (from the
    file, else the one given), or None. origin: the local origin the file carries (NPZ `origin`, the
    sonardet LAS VLR, the PLY origin comment; float64 (3,) m, file frame), or None. streamed: whether
    `chunks` reads the file chunk by chunk (text, LAS) or holds it whole (PLY, NPZ).
    """

    path: Path
    format: str
    crs: str | None
    origin: np.ndarray | None
    streamed: bool
    chunk_points: int
    _pending: tuple[PointCloud | None, Iterator[PointCloud]] | None = field(default=None, repr=False)
    #: How the file is read (vertical direction, columns, the CRS given); its coordinates' own CRS.
    source: SurveySource | None = None
    input_crs: str | None = None

    def chunks(self) -> Iterator[np.ndarray]:
        """Yield the survey's coordinates as float64 (n, 3) arrays (m, the file's frame) of at most
        `chunk_points` rows, in file order; the values are those `read_points` returns. The first pass
        goes on from the chunk `open_survey` read; a later call reads the file again."""
        pending, self._pending = self._pending, None
        if pending is None:
            source = self.source or SurveySource(self.path, self.crs)
            pending = (None, survey_chunks(source, self.chunk_points)[1])
        first, rest = pending
        if first is not None:
            yield first.xyz
        for chunk in rest:
            yield chunk.xyz


def open_survey(path, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS, *,
                z_positive: str | None = None, columns=None) -> SurveyReader:
    """Open a survey file (any suffix `read_points` takes) for chunked reading through
    `sonardet.survey.source.survey_chunks` (vertical direction, columns, longitude/latitude projected to
    UTM, the grid check of GeoTIFF/BAG); the first chunk is read here, so the CRS and origin are known
    and a file that cannot be read fails here.

    crs: the CRS of the coordinates when the file carries none (text files never do); a file declaring
    another CRS raises PointCloudError, as `read_points` does. z_positive, columns: as for
    ``sonardet detect`` (`SurveySource`). chunk_points: points per chunk (>= 1). Text, LAS/LAZ and raster
    files are streamed; PLY and NPZ files are read whole here. The reader's ``crs`` is the working CRS
    (UTM for geographic input), ``input_crs`` the file's own. Raises FileNotFoundError,
    UnsupportedFormatError / PointCloudError (ValueError) like `read_points`.
    """
    p = Path(path)
    module = format_module(p)
    source = SurveySource.of(p, crs=crs, z_positive=z_positive, columns=columns)
    head, chunks = survey_chunks(source, chunk_points)
    first = next(chunks)
    return SurveyReader(p, module.NAME, first.crs, first.origin, module.STREAMED, int(chunk_points),
                        (first, chunks), source, head.input_crs)


# ------------------------------------------------------------------------------------------- split
def _tile_doc(tile: Tile, n_points: int, file: str | None) -> dict:
    x0, y0, x1, y1 = tile.core
    owns = [None if tile.ix == 0 else x0, None if tile.iy == 0 else y0,
            None if tile.ix == tile.nx - 1 else x1, None if tile.iy == tile.ny - 1 else y1]
    return {"id": tile.id, "ix": tile.ix, "iy": tile.iy, "core": list(tile.core), "padded": list(tile.padded),
            "owns": owns, "n_points": int(n_points), "file": file}


def _spool_survey(reader: SurveyReader, spool_path: Path, cell_m: float) -> tuple[int, CellStats]:
    """Pass 1 of the split: the survey's coordinates, chunk by chunk, to a float64 spool file; returns
    (number of points, the occupied cells of a `cell_m` grid with their counts and x, y, z ranges)."""
    n, cells = 0, CellStats(float(cell_m))
    with open(spool_path, "wb") as fh:
        for xyz in reader.chunks():
            xyz = np.ascontiguousarray(xyz, dtype=np.float64)
            xyz.tofile(fh)
            n += len(xyz)
            cells = cells.merge(CellStats.of(xyz, cell_m))
            log.info("%s: read %d points", reader.path.name, n)
    if n == 0:
        raise PointCloudError(f"{reader.path}: no points")
    return n, cells


def _cut_spool(spool_path: Path, spool_dir: Path, tiles: list[Tile], chunk_points: int,
               fliers: Fliers | None) -> dict[str, int]:
    """Pass 2 of the split: the spool cut chunk by chunk, each chunk's tile subsets appended to that
    tile's spool ``{tile}.f64``; returns tile id -> number of points. Flier points are left out unless
    kept; the first few are recorded in `fliers.points`."""
    counts = {t.id: 0 for t in tiles}
    listed = []
    with open(spool_path, "rb") as src:  # plain reads, not a memory map: RSS stays at one chunk
        while len(chunk := np.fromfile(src, dtype=np.float64, count=3 * chunk_points)):
            chunk = chunk.reshape(-1, 3)
            if fliers is not None:
                mask = fliers.cells.contains(chunk)
                listed += list(chunk[mask][: FLIERS_LISTED - len(listed)])
                chunk = chunk if fliers.kept else chunk[~mask]
                if not len(chunk):
                    continue
            clo, chi = chunk[:, :2].min(0), chunk[:, :2].max(0)
            for t in tiles:
                x0, y0, x1, y1 = t.padded
                if x0 > chi[0] or x1 < clo[0] or y0 > chi[1] or y1 < clo[1]:
                    continue
                idx = tile_points(chunk, t)
                if len(idx):
                    with open(spool_dir / f"{t.id}.f64", "ab") as fh:
                        chunk[idx].tofile(fh)
                    counts[t.id] += len(idx)
    if fliers is not None:
        fliers.points = np.array(listed).reshape(-1, 3)
    return counts


def _write_tiles(tiles: list[Tile], counts: dict[str, int], spool_dir: Path, tiles_dir: Path, index_path: Path,
                 crs: str | None, origin: np.ndarray) -> list[dict]:
    """The tiles' NPZ files from their spools, one tile in memory at a time; returns the index's tile
    entries (`_tile_doc`)."""
    docs = []
    for k, t in enumerate(tiles, 1):
        file = None
        if counts[t.id]:
            raw = spool_dir / f"{t.id}.f64"
            xyz = np.fromfile(raw, dtype=np.float64).reshape(-1, 3)
            write_points(tiles_dir / f"{t.id}.npz", PointCloud(xyz, crs=crs, origin=origin), compress=False)
            raw.unlink()
            file = Path(os.path.relpath(tiles_dir / f"{t.id}.npz", index_path.parent)).as_posix()
            log.info("tile %d/%d %s: %d points", k, len(tiles), t.id, counts[t.id])
        else:
            log.info("tile %d/%d %s: no points, no file", k, len(tiles), t.id)
        docs.append(_tile_doc(t, counts[t.id], file))
    return docs


def _plan(cells: CellStats, tile_m, overlap_m, min_overlap_m, keep_fliers: bool):
    """(fliers or None, bounds [xmin, ymin, xmax, ymax] and z range of the points used, tiles near them)."""
    is_flier = find_fliers(cells)
    fliers = Fliers(cells.select(is_flier), FLIER_GAP_M, FLIER_MAX_POINTS, kept=keep_fliers) if is_flier.any() else None
    used = cells if fliers is None or keep_fliers else cells.select(~is_flier)
    lo, hi = used.bounds()
    bounds = [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])]
    return fliers, bounds, [float(lo[2]), float(hi[2])], plan_tiles(bounds, tile_m, overlap_m, min_overlap_m,
                                                                     near=used.rects())


def split_survey(path, tiles_dir, index_path, *, survey: str, tile_m: float = DEFAULT_TILE_M,
                 overlap_m: float = 3.0, crs: str | None = None, min_overlap_m: float | None = None,
                 chunk_points: int = DEFAULT_CHUNK_POINTS, keep_fliers: bool = False,
                 z_positive: str | None = None, columns=None) -> dict:
    """Cut a survey file into tiles: ``tiles_dir/{tile}.npz`` per non-empty tile and the tile index
    JSON at `index_path`; returns the index document.

    Tiles: `plan_tiles` over the x/y bounds of the points used with `tile_m` and `overlap_m` (m),
    checked against `min_overlap_m` (the largest object footprint, m; see `object_footprint_m`), and
    only near the occupied cells of a `tile_m` grid, exactly as `detect_tiled` plans them. Fliers
    (`sonardet.survey.extent.find_fliers`: a few soundings more than 100 m from the rest) are left out
    unless `keep_fliers`, and reported (log WARNING, index entry `fliers`). A tile's NPZ holds the points
    of its padded rectangle (`tile_points`: borders included) in file order: ``xyz`` float64 (m, the
    survey's coordinates, as read), ``origin`` (the survey's local origin) and ``crs`` (when known).
    Planned tiles whose padded rectangle holds no point get no file (``file: null`` in the index).
    The file is read through `open_survey` (``z_positive``, ``columns``, longitude/latitude projected
    to UTM), so the tiles hold the coordinates ``sonardet detect`` works on.

    Two passes over the data (see the module doc for memory): the file is read once, chunk by chunk,
    into a float64 spool in `tiles_dir` (occupied cells on the way); the spool is then cut chunk by
    chunk, each chunk's tile subsets appended to per-tile spools, which become the NPZ files one at a
    time. Spools are removed at the end, also on error. Progress is logged at INFO level.

    Index document: schema_version, survey, source, crs (the working CRS), input_crs, z_positive,
    columns, origin [x, y, z] (m), n_points (in the file),
    n_points_used, fliers (`Fliers.to_json`, null without fliers), bounds [xmin, ymin, xmax, ymax] (m) and
    z_range [zmin, zmax] (m) of the points used, tile_m, overlap_m, min_overlap_m, nx, ny (of the full
    plan over the bounds), chunk_points, streamed, frame (a note), and tiles: one {id, ix, iy, core,
    padded, owns, n_points, file} per planned tile, row by row; `core` and `padded` are [xmin, ymin,
    xmax, ymax] (m), `owns` the ownership area of `Tile.owns` with null for a side that extends to
    infinity, `file` the NPZ path relative to the index's folder (null for a tile without points).
    """
    t0 = time.perf_counter()
    plan_tiles((0.0, 0.0, 0.0, 0.0), tile_m, overlap_m, min_overlap_m)  # bad settings fail before reading
    tiles_dir, index_path = Path(tiles_dir), Path(index_path)
    reader = open_survey(path, crs=crs, chunk_points=chunk_points, z_positive=z_positive, columns=columns)
    tiles_dir.mkdir(parents=True, exist_ok=True)
    spool_dir = tiles_dir / ".spool"
    if spool_dir.exists():
        shutil.rmtree(spool_dir)
    spool_dir.mkdir()
    try:
        survey_spool = spool_dir / "survey.f64"
        n, cells = _spool_survey(reader, survey_spool, tile_m)
        fliers, bounds, z_range, tiles = _plan(cells, tile_m, overlap_m, min_overlap_m, keep_fliers)
        origin = reader.origin if reader.origin is not None else choose_origin(np.array([[*bounds[:2], z_range[0]]]))
        log.info("%s: %d points over %.1f x %.1f m (%s) -> %d tiles near the data (of %d x %d) of <= %g m, overlap "
                 "%g m", reader.path.name, n, bounds[2] - bounds[0], bounds[3] - bounds[1], reader.crs or "CRS unknown",
                 len(tiles), tiles[0].nx, tiles[0].ny, tile_m, overlap_m)
        counts = _cut_spool(survey_spool, spool_dir, tiles, reader.chunk_points, fliers)
        if fliers is not None:
            log.warning("%s", fliers.describe(str(path)))
        docs = _write_tiles(tiles, counts, spool_dir, tiles_dir, index_path, reader.crs, origin)
    finally:
        shutil.rmtree(spool_dir, ignore_errors=True)
    doc = {
        "schema_version": SCHEMA_VERSION, "survey": survey, "source": str(path), "crs": reader.crs,
        "input_crs": reader.input_crs, "z_positive": z_positive, "columns": list(columns) if columns else None,
        "origin": [float(v) for v in origin], "n_points": int(n),
        "n_points_used": int(n if fliers is None or fliers.kept else n - fliers.n_points),
        "fliers": None if fliers is None else fliers.to_json(), "bounds": bounds, "z_range": z_range,
        "tile_m": float(tile_m), "overlap_m": float(overlap_m),
        "min_overlap_m": None if min_overlap_m is None else float(min_overlap_m),
        "nx": tiles[0].nx, "ny": tiles[0].ny, "chunk_points": reader.chunk_points, "streamed": reader.streamed,
        "frame": "core, padded, owns, bounds and tile points in the survey's coordinates (crs; metres); "
                 "local = survey - origin; cores half-open [min, max) except the last column/row; owns: null "
                 "= unbounded",
        "tiles": docs,
    }
    atomic_write_text(index_path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    log.info("%s: %d tiles written (%d empty) in %.1f s", reader.path.name, sum(d["file"] is not None for d in docs),
             sum(d["file"] is None for d in docs), time.perf_counter() - t0)
    return doc


# ------------------------------------------------------------------------------------------- index
_INDEX_KEYS = ("schema_version", "survey", "crs", "origin", "n_points", "bounds", "tile_m", "overlap_m", "nx",
               "ny", "tiles")


def read_tile_index(path) -> tuple[dict, list[Tile]]:
    """Read a tile index JSON written by `split_survey`: (document, tiles as `Tile`, in index order).

    Rectangles are read back bit for bit (JSON floats round-trip). Raises ValueError naming the file
    for a missing key, another schema_version or an inconsistent tile entry."""
    path = Path(path)
    doc = read_json_file(path, "tile index", hint="delete it and rerun the survey_tiles job")
    missing = [k for k in _INDEX_KEYS if not isinstance(doc, dict) or k not in doc]
    if missing:
        raise ValueError(f"{path}: not a tile index (missing {', '.join(missing)}); rerun the survey_tiles job")
    if doc["schema_version"] != SCHEMA_VERSION:
        raise ValueError(f"{path}: schema_version {doc['schema_version']!r} is not {SCHEMA_VERSION}; rerun the "
                         "survey_tiles job with this version of sonardet")
    tiles = []
    for i, t in enumerate(doc["tiles"]):
        try:
            tiles.append(Tile(str(t["id"]), int(t["ix"]), int(t["iy"]), int(doc["nx"]), int(doc["ny"]),
                              tuple(float(v) for v in t["core"]), tuple(float(v) for v in t["padded"])))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{path}: tiles[{i}] is malformed ({exc!r})") from None
        if len(tiles[-1].core) != 4 or len(tiles[-1].padded) != 4:
            raise ValueError(f"{path}: tiles[{i}]: core and padded must be 4 numbers [xmin, ymin, xmax, ymax]")
    return doc, tiles


def tile_ids(index_path) -> list[str]:
    """Ids of the tiles of a tile index that hold points (the tiles that get a detection job)."""
    doc, _ = read_tile_index(index_path)
    return [t["id"] for t in doc["tiles"] if t["file"] is not None]


def read_tile_points(path) -> PointCloud:
    """A tile's points (`read_points` of its NPZ): xyz float64 (m, the survey's coordinates), origin,
    crs. Raises PointCloudError for an empty or malformed file."""
    return read_points(path)
