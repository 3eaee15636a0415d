"""LAS / LAZ point clouds through laspy (LAZ via the lazrs backend).

Reading: scaled coordinates ``X * scale + offset`` as float64 metres. Extra-bytes fields always
become attributes; standard point-record fields (``intensity``, ``classification``, ``gps_time``,
...) become attributes only when they carry information, i.e. are not all 0 (``return_number`` and
``number_of_returns`` also not all 1, the writer's default). A file whose header counts no points
is refused ("no points").

CRS on read: ``header.parse_crs()`` (pyproj: the OGC WKT VLR, else the GeoTIFF keys), as a
``sonardet.io.crs.crs_string`` (``"EPSG:32610"``, ``"EPSG:32610+5703"`` for a compound CRS, else WKT); files
of older sonardet versions may hold the CRS only in a ``sonardet`` VLR (user id ``sonardet``, record 1,
UTF-8 text), which is read when no standard record exists.

Writing: LAS 1.4, point format 6, scales ``las_scale_m`` (default 0.001 m) and offsets at the data
minimum floored to a whole metre, so the quantisation error is at most ``las_scale_m / 2``. Attributes
named like a format-6 standard field go there if their values fit it losslessly (else an error
asks for a rename); all others become extra-bytes fields of their own dtype (bool as uint8).
``return_number`` and ``number_of_returns`` default to 1. CRS: a WKT VLR through pyproj
(``header.add_crs``; compound and vertical CRSs included); a CRS pyproj does not understand is refused.
``PointCloud.origin`` goes into ``sonardet`` record 2 (three little-endian float64). The creation date is
``SOURCE_DATE_EPOCH`` when set, else today. :func:`open_writer` writes a file chunk by chunk (LAZ too),
for point sets larger than memory.

Chunked reading (:func:`iter_chunks`) streams the points through laspy's chunk iterator (LAZ too) and
yields x, y, z only, scaled as :func:`read` scales them, with the file's CRS and origin.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from datetime import date, datetime, timezone
from pathlib import Path

import laspy
import numpy as np

from sonardet import __version__
from sonardet.io.atomic import atomic_path
from sonardet.io.crs import CrsError, crs_string, parse_crs
from sonardet.io.points.core import (
    DEFAULT_CHUNK_POINTS,
    PointCloud,
    PointCloudError,
    check_plausible,
    merge_crs,
)

#: What laspy and its LAZ backends raise on a truncated or damaged file (lazrs raises a RuntimeError
#: subclass, "failed to fill whole buffer"); the readers turn these into a PointCloudError naming the file.
_LAS_ERRORS = (laspy.errors.LaspyException, OSError, ValueError, EOFError, struct.error, RuntimeError)

__all__ = [
    "NAME", "SUFFIXES", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS", "read", "write", "iter_chunks", "open_writer",
]

#: Format key (``sonardet.io.points.point_format``).
NAME = "las"
#: File suffixes of this format (``.laz``: compressed).
SUFFIXES: tuple[str, ...] = (".las", ".laz")
#: Whether :func:`iter_chunks` reads the file chunk by chunk.
STREAMED = True
#: Keywords of ``read_points`` / ``write_points`` this format takes.
READ_OPTIONS: tuple[str, ...] = ()
WRITE_OPTIONS: tuple[str, ...] = ("las_scale_m",)

SONARDET_VLR_USER = "sonardet"
_VLR_CRS = 1
_VLR_ORIGIN = 2


# ---------------------------------------------------------------------------- CRS helpers
def _read_crs(las) -> str | None:
    """CRS string of a LAS file (see the module docstring), or None."""
    try:
        parsed = las.header.parse_crs()
    except Exception:  # malformed CRS records (laspy raises several types): try the sonardet record
        parsed = None
    if parsed is not None:
        return crs_string(parsed)
    for vlr in list(las.header.vlrs) + list(getattr(las, "evlrs", None) or []):
        if vlr.user_id == SONARDET_VLR_USER and vlr.record_id == _VLR_CRS:
            text = bytes(vlr.record_data).decode("utf-8", errors="replace").rstrip("\0").strip()
            if text:
                return text
    return None


def _read_origin(las: laspy.LasData, where: str) -> np.ndarray | None:
    for vlr in las.header.vlrs:
        if vlr.user_id == SONARDET_VLR_USER and vlr.record_id == _VLR_ORIGIN:
            data = bytes(vlr.record_data)
            if len(data) != 24:
                raise PointCloudError(f"{where}: sonardet origin VLR holds {len(data)} bytes, expected 24")
            return np.array(struct.unpack("<3d", data), dtype=np.float64)
    return None


def _add_crs(header: laspy.LasHeader, crs: str, where: str) -> None:
    """Attach ``crs`` to ``header`` as an OGC WKT VLR (LAS 1.4): pyproj's WKT1 (GDAL flavour, the OGC
    01-009 form LAS 1.4 names and LAStools, PDAL and CloudCompare read), WKT2 for a CRS WKT1 cannot
    express; a CRS pyproj does not understand raises PointCloudError."""
    from laspy.vlrs.known import WktCoordinateSystemVlr

    try:
        obj = parse_crs(crs, where)
    except CrsError as exc:
        raise PointCloudError(str(exc)) from None
    wkt = obj.to_wkt("WKT1_GDAL") or obj.to_wkt()
    header.vlrs.append(WktCoordinateSystemVlr(wkt))
    header.global_encoding.wkt = True


def _creation_date() -> date:
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    if epoch and epoch.strip().isdigit():
        return datetime.fromtimestamp(int(epoch), tz=timezone.utc).date()
    return date.today()


# ---------------------------------------------------------------------------- read / write
def read(path: str | Path, *, crs: str | None = None) -> PointCloud:
    """Read a ``.las``/``.laz`` file: float64 scaled x, y, z (metres, the file's frame), attributes, CRS
    and origin (see the module docstring); ``crs`` as in ``read_points``."""
    p = Path(path)
    where = str(p)
    try:
        las = laspy.read(p)
    except _LAS_ERRORS as exc:
        raise PointCloudError(f"{where}: not a readable LAS/LAZ file ({exc})") from exc
    n = int(las.header.point_count)
    if n == 0 or len(las.points) == 0:
        raise PointCloudError(f"{where}: no points (the LAS header counts {n} points)")
    if len(las.points) != n:
        raise PointCloudError(f"{where}: header counts {n} points but {len(las.points)} were read; the file is truncated")
    xyz = np.empty((n, 3), dtype=np.float64)
    scales, offsets = las.header.scales, las.header.offsets
    for i, raw in enumerate((las.X, las.Y, las.Z)):
        xyz[:, i] = np.asarray(raw, dtype=np.float64) * scales[i] + offsets[i]

    attrs: dict[str, np.ndarray] = {}
    extra = set(las.point_format.extra_dimension_names)
    for name in las.point_format.dimension_names:
        if name in ("X", "Y", "Z"):
            continue
        values = np.asarray(las[name])
        if name not in extra:
            defaults = (0, 1) if name in ("return_number", "number_of_returns") else (0,)
            if any(np.all(values == d) for d in defaults):
                continue
        attrs[name] = np.array(values)
    return PointCloud(
        xyz,
        attrs,
        crs=merge_crs(_read_crs(las), crs, where),
        source=where,
        origin=_read_origin(las, where),
    )


def _new_header(where: str, lo: np.ndarray, hi: np.ndarray, scale_m: float, crs: str | None,
                origin: np.ndarray | None) -> laspy.LasHeader:
    """A LAS 1.4 format-6 header for points within [lo, hi] (m): scales ``scale_m``, offsets at ``lo``
    floored to a whole metre, the CRS VLR and the sonardet origin VLR; raises for a bad scale or a span
    int32 coordinates cannot hold."""
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise PointCloudError(f"{where}: las_scale_m must be a positive number of metres, got {scale_m!r}")
    offsets = np.floor(np.asarray(lo, dtype=np.float64))
    span = float((np.asarray(hi, dtype=np.float64) - offsets).max())
    if span / scale_m >= 2**31 - 1:
        raise PointCloudError(
            f"{where}: the cloud spans {span:.1f} m, too much for a LAS scale of {scale_m} m (int32 "
            "coordinates); pass a coarser las_scale_m or split the cloud"
        )
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([scale_m] * 3, dtype=np.float64)
    header.offsets = offsets
    header.generating_software = f"sonardet {__version__}"
    header.system_identifier = "sonardet"
    header.creation_date = _creation_date()
    if crs is not None:
        _add_crs(header, crs, where)
    if origin is not None:
        header.vlrs.append(
            laspy.VLR(SONARDET_VLR_USER, _VLR_ORIGIN, "local origin x y z (m)", struct.pack("<3d", *origin))
        )
    return header


def _split_attributes(header: laspy.LasHeader, attributes: Mapping[str, np.ndarray], where: str):
    """(standard fields, extra-bytes fields) of ``attributes``: names of format-6 fields whose values fit
    go to the first, the others to the second (bool as uint8); clashes and long names raise."""
    standard = {d.name: d for d in header.point_format.dimensions if d.name not in ("X", "Y", "Z")}
    to_standard: dict[str, np.ndarray] = {}
    to_extra: dict[str, np.ndarray] = {}
    for name, values in attributes.items():
        if name in standard:
            to_standard[name] = _fit_standard(values, standard[name], where)
            continue
        if len(name.encode("utf-8")) > 32:
            raise PointCloudError(f"{where}: attribute name {name!r} is longer than LAS's 32 bytes; rename it")
        if name.lower() in (s.lower() for s in standard) or name in ("X", "Y", "Z"):
            raise PointCloudError(f"{where}: attribute {name!r} clashes with a LAS field name; rename it")
        to_extra[name] = values.astype(np.uint8) if values.dtype.kind == "b" else values
    return to_standard, to_extra


def _fill(record, xyz: np.ndarray, fields: Mapping[str, np.ndarray]) -> None:
    """Set the coordinates (m) and fields of a LasData or ScaleAwarePointRecord; returns default to 1."""
    record.x, record.y, record.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    for name in ("return_number", "number_of_returns"):
        if name not in fields:
            record[name] = np.ones(len(xyz), dtype=np.uint8)
    for name, values in fields.items():
        record[name] = values


def write(path: str | Path, cloud: PointCloud, *, las_scale_m: float = 0.001) -> None:
    """Write ``cloud`` as LAS 1.4 point format 6 (``.laz``: compressed), atomically.

    Coordinates (metres, the cloud's frame) are quantised to ``las_scale_m`` metres (default 1 mm),
    offsets at the data minimum floored to a whole metre. See the module docstring for attributes and CRS.
    """
    p = Path(path)
    where = str(p)
    xyz = cloud.xyz
    header = _new_header(where, xyz.min(axis=0), xyz.max(axis=0), las_scale_m, cloud.crs, cloud.origin)
    to_standard, to_extra = _split_attributes(header, cloud.attributes, where)
    if to_extra:
        header.add_extra_dims([laspy.ExtraBytesParams(name=k, type=v.dtype) for k, v in to_extra.items()])
    las = laspy.LasData(header)
    _fill(las, xyz, {**to_standard, **to_extra})
    compress = p.name.lower().endswith(".laz")
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        las.write(fh, do_compress=compress)


@contextmanager
def open_writer(path: str | Path, *, bounds: tuple, crs: str | None = None, las_scale_m: float = 0.001,
                extra_dims: Mapping[str, tuple] | None = None, vlrs: tuple = ()):
    """Write a LAS 1.4 format-6 file (``.laz``: compressed) chunk by chunk, atomically: yields a function
    ``write(xyz, fields)`` taking float64 (n, 3) coordinates (m, the CRS's frame) and a dict of per-point
    fields (standard format-6 fields such as ``classification``, and the extra dims), each call appending
    n points. The file replaces ``path`` only when the block ends without error.

    bounds: (lo, hi), the (3,) minimum and maximum of every point to come (m; offsets at lo floored to a
    metre, the span checked against ``las_scale_m``). extra_dims: name -> (numpy dtype, description of at
    most 32 characters), extra-bytes fields that CloudCompare and PDAL show as scalar fields. vlrs: more
    ``laspy.VLR`` records. Memory: one chunk.
    """
    p = Path(path)
    where = str(p)
    header = _new_header(where, bounds[0], bounds[1], las_scale_m, crs, None)
    if extra_dims:
        header.add_extra_dims([laspy.ExtraBytesParams(name=k, type=np.dtype(t), description=d[:31])
                               for k, (t, d) in extra_dims.items()])
    header.vlrs.extend(vlrs)
    with atomic_path(p) as tmp:
        with laspy.open(tmp, mode="w", header=header, do_compress=p.name.lower().endswith(".laz")) as writer:
            def write_chunk(xyz: np.ndarray, fields: Mapping[str, np.ndarray]) -> None:
                record = laspy.ScaleAwarePointRecord.zeros(len(xyz), header=header)
                _fill(record, xyz, fields)
                writer.write_points(record)

            yield write_chunk


def _read_header(path: Path) -> tuple[str | None, np.ndarray | None, int]:
    """(CRS, origin (m) or None, number of points) from the header and VLRs of a LAS/LAZ file."""
    where = str(path)
    try:
        with laspy.open(path) as reader:
            file_crs = _read_crs(reader)
            origin = _read_origin(reader, where)
            n = int(reader.header.point_count)
    except _LAS_ERRORS as exc:
        raise PointCloudError(f"{where}: not a readable LAS/LAZ file ({exc})") from exc
    return file_crs, origin, n


def iter_chunks(
    path: str | Path, *, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS
) -> Iterator[PointCloud]:
    """The file's x, y, z (float64 metres, the file's frame, scaled as :func:`read` scales them) in chunks
    of at most ``chunk_points`` points, in file order, each a :class:`PointCloud` without attributes
    carrying the file's CRS (``crs`` as in ``read_points``) and origin. A file whose header counts no
    points, or more points than it holds, is refused."""
    p = Path(path)
    where = str(p)
    file_crs, origin, total = _read_header(p)
    if total == 0:
        raise PointCloudError(f"{where}: no points (the LAS header counts 0 points)")
    merged = merge_crs(file_crs, crs, where)
    n = 0
    try:
        with laspy.open(p) as reader:
            scales, offsets = reader.header.scales, reader.header.offsets
            for pts in reader.chunk_iterator(chunk_points):
                xyz = np.empty((len(pts), 3), dtype=np.float64)
                for i, raw in enumerate((pts.X, pts.Y, pts.Z)):
                    xyz[:, i] = np.asarray(raw, dtype=np.float64) * scales[i] + offsets[i]
                check_plausible(xyz, where, first_point=n)
                n += len(xyz)
                yield PointCloud(xyz, crs=merged, source=where, origin=origin)
    except _LAS_ERRORS as exc:
        raise PointCloudError(f"{where}: not a readable LAS/LAZ file ({exc})") from exc
    if n != total:
        raise PointCloudError(f"{where}: header counts {total} points but {n} were read; the file is truncated")


def _fit_standard(values: np.ndarray, dim, where: str) -> np.ndarray:
    """``values`` cast to the standard LAS field ``dim`` if that is lossless; raise otherwise."""
    if dim.kind == laspy.DimensionKind.FloatingPoint:
        if values.dtype.kind == "f" and values.dtype.itemsize > dim.dtype.itemsize:
            raise PointCloudError(f"{where}: attribute {dim.name!r} ({values.dtype}) does not fit LAS {dim.dtype}; rename it")
        return values.astype(dim.dtype)
    finite = values.dtype.kind != "f" or bool(np.all(np.isfinite(values)))
    as_int = values.astype(np.int64) if finite else np.zeros(len(values), dtype=np.int64)
    lossless = finite and np.array_equal(as_int, values)
    if not lossless or (len(as_int) and (as_int.min() < int(dim.min) or as_int.max() > int(dim.max))):
        raise PointCloudError(
            f"{where}: attribute {dim.name!r} has values that do not fit the LAS field {dim.name} "
            f"(integers {int(dim.min)}..{int(dim.max)}); rename the attribute so it is stored as an "
            "extra-bytes field with its own dtype"
        )
    return as_int.astype(dim.dtype) if dim.dtype is not None else as_int.astype(np.uint8)
