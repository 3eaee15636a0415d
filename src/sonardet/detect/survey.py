"""Survey-scale detection as one job per tile: survey settings, a streaming tile split, the tile index,
the merge of the tiles' detections and the survey outputs.

The workflow (rules/survey.smk) runs the model-based detector on a survey file in three steps:

1. `split_survey` (checkpoint ``survey_tiles``): reads the survey in chunks, plans the tiles over the
   points' x/y bounds (`sonardet.detect.tiling.plan_tiles`, the plan `detect_tiled` and ``sonardet
   detect`` make) and writes the points of each tile's padded rectangle to ``tiles/{tile}.npz`` and the
   tile index JSON (`read_tile_index`, `tile_ids`).
2. one detection job per tile that holds points, on that tile's points only (`read_tile_points`), so
   its memory is bounded by the tile (peak RSS 264 MB for a 380 000-point 46 m x 46 m padded tile of
   bare seabed, against the whole survey held by ``sonardet detect``);
3. `merge_survey_detections` merges them with `sonardet.detect.tiling.merge_tile_detections` (each
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
and NPZ files have no chunked reader here: they are read whole (24 x N bytes), then cut in chunks.
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
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import SCHEMA_VERSION
from ..io.atomic import atomic_write_text
from ..io.origin import choose_origin
from ..io.pointcloud import PointCloud, PointCloudError, point_format, read_points, write_npz
from .tiling import Tile, merge_tile_detections, plan_tiles, tile_points

log = logging.getLogger(__name__)

__all__ = [
    "SurveyReader",
    "enabled_surveys",
    "merge_survey_detections",
    "object_footprint_m",
    "open_survey",
    "read_tile_index",
    "read_tile_points",
    "split_survey",
    "survey_defaults",
    "survey_settings",
    "tile_ids",
    "write_survey_detections",
]

#: Points read per chunk by default (text and LAS); 1e6 points of x y z text take about 48 MB.
DEFAULT_CHUNK_POINTS = 1_000_000


# ------------------------------------------------------------------------------------------- settings
def survey_defaults() -> dict:
    """Default settings of one entry of the config's `surveys` block, from the config schema
    (`surveys.additionalProperties.properties.*.default`): enabled, crs, method, tile_m (m), overlap_m
    (m), chunk_points. `path` has no default."""
    from ..config import read_schema

    props = read_schema()["properties"]["surveys"]["additionalProperties"]["properties"]
    return {k: v["default"] for k, v in props.items() if "default" in v}


def survey_settings(name: str, entry: Mapping) -> dict:
    """One survey's settings: `entry` (a validated `surveys.<name>` config block) completed with the
    schema's defaults, plus its `name`. Raises ValueError when `path` is missing."""
    if "path" not in entry:
        raise ValueError(f"surveys.{name}: needs `path`, the survey's point-cloud file")
    return {**survey_defaults(), **dict(entry), "name": name}


def enabled_surveys(surveys: Mapping) -> tuple[dict, list[str]]:
    """The surveys the workflow runs: (name -> settings of `survey_settings`, messages).

    Surveys with `enabled: false` are left out silently; a survey whose file does not exist is left
    out with a message (for the workflow to print at start-up) saying how to fix or silence it.
    Relative paths are relative to the working directory.
    """
    out, messages = {}, []
    for name, entry in (surveys or {}).items():
        s = survey_settings(name, entry)
        if not s["enabled"]:
            continue
        if not Path(s["path"]).is_file():
            messages.append(
                f"sonardet: surveys.{name}.path {s['path']} not found: the survey {name!r} is left out of this "
                f"run (set surveys.{name}.path to the survey file, or surveys.{name}.enabled: false to "
                "silence this)")
            continue
        out[name] = s
    return out, messages


def object_footprint_m(objects: Mapping) -> float:
    """Largest horizontal footprint (m) of the classes' meshes at any yaw: twice the largest distance
    of a vertex from the class's vertical axis (the canonical frame's z axis), as ``sonardet detect``
    computes it. The tiles' overlap must be at least this for the ownership rule to be exact.
    `objects`: class -> ObjectInfo (anything with `.mesh.vertices`)."""
    if not objects:
        raise ValueError("object_footprint_m: no object models given")
    return max(2.0 * float(np.max(np.hypot(*np.asarray(o.mesh.vertices)[:, :2].T))) for o in objects.values())


# --------------------------------------------------------------------------------- chunked reading
@dataclass
class SurveyReader:
    """A survey file opened for chunked reading (see `open_survey`).

    path: the file. format: 'text', 'las', 'ply' or 'npz'. crs: the CRS of the coordinates (from the
    file, else the one given), or None. origin: the local origin the file carries (NPZ `origin`, the
    sonardet LAS VLR; float64 (3,) m, file frame), or None. streamed: whether `chunks` reads the file
    chunk by chunk (text, LAS) or holds it whole (PLY, NPZ).
    """

    path: Path
    format: str
    crs: str | None
    origin: np.ndarray | None
    streamed: bool
    chunk_points: int
    _cloud: PointCloud | None = field(default=None, repr=False)

    def chunks(self) -> Iterator[np.ndarray]:
        """Yield the survey's coordinates as float64 (n, 3) arrays (m, the file's frame) of at most
        `chunk_points` rows, in file order; the values are those `read_points` returns."""
        if self.format == "text":
            yield from _text_chunks(self.path, self.crs, self.chunk_points)
        elif self.format == "las":
            yield from _las_chunks(self.path, self.crs, self.chunk_points)
        else:
            xyz = self._cloud.xyz
            for a in range(0, len(xyz), self.chunk_points):
                yield xyz[a:a + self.chunk_points]


def open_survey(path, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS) -> SurveyReader:
    """Open a survey point cloud (any suffix `read_points` takes) for chunked reading.

    crs: the CRS of the coordinates when the file carries none (text files never do); a file declaring
    another CRS raises PointCloudError, as `read_points` does. chunk_points: points per chunk (>= 1).
    Text and LAS/LAZ files are streamed; PLY and NPZ files are read whole here. Raises
    FileNotFoundError, UnsupportedFormatError / PointCloudError (ValueError) like `read_points`.
    """
    p = Path(path)
    fmt = point_format(p)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such point-cloud file")
    if int(chunk_points) < 1:
        raise ValueError(f"chunk_points must be >= 1, got {chunk_points!r}")
    chunk_points = int(chunk_points)
    if fmt == "text":
        from ..io.pointcloud import _merge_crs

        return SurveyReader(p, fmt, _merge_crs(None, crs, str(p)), None, True, chunk_points)
    if fmt == "las":
        return _open_las(p, crs, chunk_points)
    cloud = read_points(p, crs=crs)
    return SurveyReader(p, fmt, cloud.crs, cloud.origin, False, chunk_points, cloud)


def _reader_error(path: Path, crs: str | None, what: str):
    """Raise the whole-file reader's error for a problem found in a chunk (it names the line and the
    fix); if the whole-file reader accepts the file after all, raise a PointCloudError saying `what`."""
    read_points(path, crs=crs)
    raise PointCloudError(f"{path}: {what}; the chunked reader cannot read it (read_points can: convert the "
                          "file to .npz)")


def _text_chunks(path: Path, crs: str | None, chunk_points: int) -> Iterator[np.ndarray]:
    """x, y, z of a text point cloud, `chunk_points` rows at a time, parsed as `sonardet.io.text`
    parses the whole file (same layout detection, same pandas C parser and options: identical float64
    values). A problem in a chunk (wrong column count, a non-number, NaN/Inf coordinates) is reported
    by `read_points`, whose message names the line; attribute columns are not kept."""
    import pandas as pd

    from ..io import text as tx

    where = str(path)
    suffix, gz = tx._base_suffix(path)
    layout = tx._peek(path, gz, suffix == ".pts")
    ncols = len(layout.first_tokens)
    names = [h.strip() for h in layout.header] if layout.header is not None else (
        ["x", "y", "z"] + [f"col{i}" for i in range(3, ncols)])
    if len(names) < 3 or len(set(names)) != len(names):
        _reader_error(path, crs, "fewer than 3 or duplicate columns")
    xi, yi, zi, from_depth = tx._resolve(names, where, False)
    sep_kw: dict = {"sep": r"\s+"} if layout.delim is None else {"sep": layout.delim, "skipinitialspace": True}
    n, checked = 0, False
    try:
        reader = pd.read_csv(path, header=None, skiprows=layout.skip, comment="#", engine="c",
                             compression="gzip" if gz else None, encoding=tx._ENCODING, encoding_errors="replace",
                             skip_blank_lines=True, index_col=False, chunksize=chunk_points, **sep_kw)
        with reader:
            for df in reader:
                if df.shape[1] != len(names):
                    _reader_error(path, crs, f"a line after point {n} has {df.shape[1]} columns, not {len(names)}")
                if not checked and df.isna().to_numpy().any():
                    # Short lines read as NaN, but so does a legitimate 'nan' attribute: let the whole-file
                    # reader decide once (it raises naming the line, or accepts the file).
                    read_points(path, crs=crs)
                    checked = True
                cols = [df.iloc[:, i] for i in (xi, yi, zi)]
                if not all(pd.api.types.is_numeric_dtype(c) for c in cols):
                    _reader_error(path, crs, f"a coordinate after point {n} is not a number")
                xyz = np.empty((len(df), 3), dtype=np.float64)
                for k, c in enumerate(cols):
                    xyz[:, k] = c.to_numpy(dtype=np.float64)
                if from_depth:
                    np.negative(xyz[:, 2], out=xyz[:, 2])
                if not np.isfinite(xyz).all():
                    _reader_error(path, crs, f"non-finite coordinates after point {n}")
                n += len(xyz)
                yield xyz
    except (pd.errors.ParserError, pd.errors.EmptyDataError, OSError, EOFError, UnicodeError) as exc:
        _reader_error(path, crs, f"cannot parse the file ({exc})")
    if n == 0:
        raise PointCloudError(f"{where}: no points")
    if layout.count is not None and layout.count != n:
        raise PointCloudError(f"{where}: the PTS count line says {layout.count} points but {n} were read; "
                              "fix the count line or the truncated file")


def _open_las(path: Path, crs: str | None, chunk_points: int) -> SurveyReader:
    import laspy

    from ..io import las as lx
    from ..io.pointcloud import _merge_crs

    where = str(path)
    try:
        with laspy.open(path) as reader:
            file_crs = lx._read_crs(reader)
            origin = lx._read_origin(reader, where)
            n = int(reader.header.point_count)
    except (laspy.errors.LaspyException, OSError, ValueError, EOFError) as exc:
        raise PointCloudError(f"{where}: not a readable LAS/LAZ file ({exc})") from exc
    if n == 0:
        raise PointCloudError(f"{where}: no points (the LAS header counts 0 points)")
    return SurveyReader(path, "las", _merge_crs(file_crs, crs, where), origin, True, chunk_points)


def _las_chunks(path: Path, crs: str | None, chunk_points: int) -> Iterator[np.ndarray]:
    """x, y, z of a LAS/LAZ file, chunk by chunk, scaled as `sonardet.io.las.read_las` scales them."""
    import laspy

    where = str(path)
    n = 0
    try:
        with laspy.open(path) as reader:
            total = int(reader.header.point_count)
            scales, offsets = reader.header.scales, reader.header.offsets
            for pts in reader.chunk_iterator(chunk_points):
                xyz = np.empty((len(pts), 3), dtype=np.float64)
                for i, raw in enumerate((pts.X, pts.Y, pts.Z)):
                    xyz[:, i] = np.asarray(raw, dtype=np.float64) * scales[i] + offsets[i]
                n += len(xyz)
                yield xyz
    except (laspy.errors.LaspyException, OSError, ValueError, EOFError) as exc:
        raise PointCloudError(f"{where}: not a readable LAS/LAZ file ({exc})") from exc
    if n != total:
        raise PointCloudError(f"{where}: header counts {total} points but {n} were read; the file is truncated")


# ------------------------------------------------------------------------------------------- split
def _tile_doc(tile: Tile, n_points: int, file: str | None) -> dict:
    x0, y0, x1, y1 = tile.core
    owns = [None if tile.ix == 0 else x0, None if tile.iy == 0 else y0,
            None if tile.ix == tile.nx - 1 else x1, None if tile.iy == tile.ny - 1 else y1]
    return {"id": tile.id, "ix": tile.ix, "iy": tile.iy, "core": list(tile.core), "padded": list(tile.padded),
            "owns": owns, "n_points": int(n_points), "file": file}


def split_survey(path, tiles_dir, index_path, *, survey: str, tile_m: float = 40.0, overlap_m: float = 3.0,
                 crs: str | None = None, min_overlap_m: float | None = None,
                 chunk_points: int = DEFAULT_CHUNK_POINTS) -> dict:
    """Cut a survey file into tiles: ``tiles_dir/{tile}.npz`` per non-empty tile and the tile index
    JSON at `index_path`; returns the index document.

    Tiles: `plan_tiles` over the x/y bounds of all points with `tile_m` and `overlap_m` (m), checked
    against `min_overlap_m` (the largest object footprint, m; see `object_footprint_m`), exactly as
    `detect_tiled` plans them. A tile's NPZ holds the points of its padded rectangle (`tile_points`:
    borders included) in file order: ``xyz`` float64 (m, the survey's coordinates, as read), ``origin``
    (the survey's local origin) and ``crs`` (when known). Tiles whose padded rectangle holds no point
    get no file (``file: null`` in the index).

    Two passes over the data (see the module doc for memory): the file is read once, chunk by chunk,
    into a float64 spool in `tiles_dir` (bounds on the way); the spool is then cut chunk by chunk,
    each chunk's tile subsets appended to per-tile spools, which become the NPZ files one at a time.
    Spools are removed at the end, also on error. Progress is logged at INFO level.

    Index document: schema_version, survey, source, crs, origin [x, y, z] (m), n_points, bounds
    [xmin, ymin, xmax, ymax] (m), z_range [zmin, zmax] (m), tile_m, overlap_m, min_overlap_m, nx, ny,
    chunk_points, streamed, frame (a note), and tiles: one {id, ix, iy, core, padded, owns, n_points,
    file} per tile of the plan, row by row; `core` and `padded` are [xmin, ymin, xmax, ymax] (m), `owns`
    the ownership area of `Tile.owns` with null for a side that extends to infinity, `file` the NPZ
    path relative to the index's folder (null for a tile without points).
    """
    t0 = time.perf_counter()
    plan_tiles((0.0, 0.0, 0.0, 0.0), tile_m, overlap_m, min_overlap_m)  # bad settings fail before reading
    tiles_dir, index_path = Path(tiles_dir), Path(index_path)
    reader = open_survey(path, crs=crs, chunk_points=chunk_points)
    tiles_dir.mkdir(parents=True, exist_ok=True)
    spool_dir = tiles_dir / ".spool"
    if spool_dir.exists():
        shutil.rmtree(spool_dir)
    spool_dir.mkdir()
    try:
        # Pass 1: spool the coordinates, bounds on the way.
        n, lo, hi = 0, np.full(3, np.inf), np.full(3, -np.inf)
        survey_spool = spool_dir / "survey.f64"
        with open(survey_spool, "wb") as fh:
            for xyz in reader.chunks():
                xyz = np.ascontiguousarray(xyz, dtype=np.float64)
                xyz.tofile(fh)
                n += len(xyz)
                lo, hi = np.minimum(lo, xyz.min(0)), np.maximum(hi, xyz.max(0))
                log.info("%s: read %d points", reader.path.name, n)
        if n == 0:
            raise PointCloudError(f"{reader.path}: no points")
        reader._cloud = None  # PLY/NPZ: the whole-file copy is no longer needed
        tiles = plan_tiles((lo[0], lo[1], hi[0], hi[1]), tile_m, overlap_m, min_overlap_m)
        origin = reader.origin if reader.origin is not None else choose_origin(lo[None, :])
        log.info("%s: %d points over %.1f x %.1f m (%s) -> %d tiles (%d x %d) of <= %g m, overlap %g m",
                 reader.path.name, n, hi[0] - lo[0], hi[1] - lo[1], reader.crs or "CRS unknown", len(tiles),
                 tiles[0].nx, tiles[0].ny, tile_m, overlap_m)
        # Pass 2: cut the spool chunk by chunk; each chunk's tile subsets go to that tile's spool.
        counts = {t.id: 0 for t in tiles}
        with open(survey_spool, "rb") as src:  # plain reads, not a memory map: RSS stays at one chunk
            while len(chunk := np.fromfile(src, dtype=np.float64, count=3 * reader.chunk_points)):
                chunk = chunk.reshape(-1, 3)
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
        # Tile files, one tile in memory at a time.
        docs = []
        for k, t in enumerate(tiles, 1):
            file = None
            if counts[t.id]:
                raw = spool_dir / f"{t.id}.f64"
                xyz = np.fromfile(raw, dtype=np.float64).reshape(-1, 3)
                write_npz(tiles_dir / f"{t.id}.npz", PointCloud(xyz, crs=reader.crs, origin=origin), compress=False)
                raw.unlink()
                file = Path(os.path.relpath(tiles_dir / f"{t.id}.npz", index_path.parent)).as_posix()
                log.info("tile %d/%d %s: %d points", k, len(tiles), t.id, counts[t.id])
            else:
                log.info("tile %d/%d %s: no points, no file", k, len(tiles), t.id)
            docs.append(_tile_doc(t, counts[t.id], file))
    finally:
        shutil.rmtree(spool_dir, ignore_errors=True)
    doc = {
        "schema_version": SCHEMA_VERSION, "survey": survey, "source": str(path), "crs": reader.crs,
        "origin": [float(v) for v in origin], "n_points": int(n),
        "bounds": [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])], "z_range": [float(lo[2]), float(hi[2])],
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
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc}); rerun the survey_tiles job") from None
    missing = [k for k in _INDEX_KEYS if k not in doc]
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


# ------------------------------------------------------------------------------------------- merge
def merge_survey_detections(index: dict, tiles: list[Tile], per_tile: Mapping, dup_dist_m: float = 0.5):
    """Merge the detections of a survey's tiles (tile id -> list of detections, boxes in the survey's
    coordinates, m) with `merge_tile_detections`: each object reported once, by the tile owning its box
    centre, sorted by descending score.

    Every tile of the index that holds points must be in `per_tile` (an empty list if it found
    nothing) and no other: a lost or foreign tile raises ValueError, so nothing is merged silently
    from a partial run. Returns (detections, rows), rows one per tile of the plan: {tile, n_points,
    n_detections, n_kept (detections the tile owns before the cross-tile duplicate check)}.
    """
    expected = {t["id"] for t in index["tiles"] if t["file"] is not None}
    got = set(per_tile)
    if got != expected:
        lost, extra = sorted(expected - got), sorted(got - expected)
        raise ValueError(f"survey {index.get('survey')!r}: tile detections do not match the tile index "
                         f"(missing: {', '.join(lost) or '-'}; not in the index or empty: {', '.join(extra) or '-'})")
    by_id = {t.id: t for t in tiles}
    rows = []
    for t in index["tiles"]:
        dets = per_tile.get(t["id"], [])
        tile = by_id[t["id"]]
        rows.append({"tile": t["id"], "n_points": t["n_points"], "n_detections": len(dets),
                     "n_kept": sum(bool(tile.owns(d["box"][0], d["box"][1])) for d in dets)})
    return merge_tile_detections(dict(per_tile), tiles, dup_dist_m), rows


def write_survey_detections(dets: list, json_path, csv_path=None, geojson_path=None, *, survey: str,
                            method: str, source: str, crs: str | None, classes=None) -> dict:
    """Write a survey's merged detections (boxes in the survey's coordinates, m, rad) as the JSON of
    ``sonardet detect`` (schema_version, scene, method, source, crs, detections; `scene` is the survey's
    name: read it with ``read_detections(path, expected_scene=<survey>)``), and optionally as CSV and
    GeoJSON (`sonardet.io.export`, CRS named). Atomic writes; returns the JSON document."""
    from ..io.annotations import to_builtin, validate_detections
    from ..io.export import write_detections_csv, write_detections_geojson

    doc = {"schema_version": SCHEMA_VERSION, "scene": survey, "method": method, "source": str(source), "crs": crs,
           "detections": to_builtin(list(dets))}
    doc = validate_detections(doc, json_path, classes, survey)
    atomic_write_text(json_path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    frame = f"{crs} metres" if crs else "the survey file's coordinates (metres, CRS unknown)"
    if csv_path is not None:
        write_detections_csv(csv_path, doc["detections"],
                             origin_note=f"coordinates: {frame}, as in {Path(source).name}; yaw_rad about +z")
    if geojson_path is not None:
        write_detections_geojson(geojson_path, doc["detections"], crs=crs)
    return doc
