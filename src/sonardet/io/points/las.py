"""LAS / LAZ point clouds through laspy (LAZ via the lazrs backend).

Reading: scaled coordinates ``X * scale + offset`` as float64 metres. Extra-bytes fields always
become attributes; standard point-record fields (``intensity``, ``classification``, ``gps_time``,
...) become attributes only when they carry information, i.e. are not all 0 (``return_number`` and
``number_of_returns`` also not all 1, the writer's default). A file whose header counts no points
is refused ("no points").

CRS on read, first match wins:
  1. with ``pyproj`` installed: ``header.parse_crs()``, returned as ``"AUTH:CODE"`` (e.g.
     ``"EPSG:32610"``) or WKT when it has no authority code;
  2. without pyproj: the outermost node's ``AUTHORITY["EPSG", n]`` / ``ID["EPSG", n]`` of an OGC WKT VLR
     (else the WKT string itself), then ``ProjectedCSTypeGeoKey`` / ``GeographicTypeGeoKey`` of a
     GeoTIFF key directory VLR;
  3. the ``sonardet`` VLR written when no standard CRS record could be made (see writing).

Writing: LAS 1.4, point format 6, scales ``las_scale_m`` (default 0.001 m) and offsets at the data
minimum floored to a whole metre, so the quantisation error is at most ``las_scale_m / 2``. Attributes
named like a format-6 standard field go there if their values fit it losslessly (else an error
asks for a rename); all others become extra-bytes fields of their own dtype (bool as uint8).
``return_number`` and ``number_of_returns`` default to 1. CRS: with pyproj any CRS is written as a
WKT VLR (``header.add_crs``); without pyproj, WGS 84 / UTM zones (EPSG:326zz, 327zz) get a WKT1
VLR generated here and WKT strings are written as given; other CRS strings are kept only in a
``sonardet`` VLR (user id ``sonardet``, record 1, UTF-8 text) with a warning, which this reader
understands and other tools ignore. ``PointCloud.origin`` goes into ``sonardet`` record 2 (three
little-endian float64). The creation date is ``SOURCE_DATE_EPOCH`` when set, else today.

Chunked reading (:func:`iter_chunks`) streams the points through laspy's chunk iterator (LAZ too) and
yields x, y, z only, scaled as :func:`read` scales them, with the file's CRS and origin.
"""

from __future__ import annotations

import os
import re
import struct
import warnings
from collections.abc import Iterator
from datetime import date, datetime, timezone
from pathlib import Path

import laspy
import numpy as np
from laspy.vlrs.known import GeoKeyDirectoryVlr, WktCoordinateSystemVlr

from sonardet import __version__
from sonardet.io.atomic import atomic_path
from sonardet.io.points.core import (
    DEFAULT_CHUNK_POINTS,
    PointCloud,
    PointCloudError,
    check_plausible,
    merge_crs,
    normalize_crs,
)

#: What laspy and its LAZ backends raise on a truncated or damaged file (lazrs raises a RuntimeError
#: subclass, "failed to fill whole buffer"); the readers turn these into a PointCloudError naming the file.
_LAS_ERRORS = (laspy.errors.LaspyException, OSError, ValueError, EOFError, struct.error, RuntimeError)

__all__ = [
    "NAME", "SUFFIXES", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS", "read", "write", "iter_chunks", "utm_wkt",
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
_EPSG_NODE = re.compile(r'(?:AUTHORITY|ID)\s*\[\s*"EPSG"\s*,\s*"?(\d+)"?\s*[\],]', re.IGNORECASE)
_WKT_HEADS = ("PROJCS[", "GEOGCS[", "COMPD_CS[", "GEOCCS[", "PROJCRS[", "GEOGCRS[", "COMPOUNDCRS[", "BOUNDCRS[")
_PROJECTED_KEY = 3072
_GEOGRAPHIC_KEY = 2048


# ---------------------------------------------------------------------------- CRS helpers
def utm_wkt(crs: str) -> str | None:
    """OGC WKT1 of a WGS 84 / UTM CRS (``"EPSG:326zz"`` north, ``"EPSG:327zz"`` south), else None.

    Generated from the zone (central meridian ``6 * zone - 183`` degrees, scale 0.9996, false
    easting 500 000 m, false northing 0 or 10 000 000 m), in the form GDAL exports for these codes.
    """
    m = re.fullmatch(r"EPSG:(32[67])(\d\d)", normalize_crs(crs))
    if not m or not 1 <= int(m.group(2)) <= 60:
        return None
    zone = int(m.group(2))
    south = m.group(1) == "327"
    code = int(m.group(1) + m.group(2))
    return (
        f'PROJCS["WGS 84 / UTM zone {zone}{"S" if south else "N"}",GEOGCS["WGS 84",DATUM["WGS_1984",'
        'SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],'
        'PRIMEM["Greenwich",0,AUTHORITY["EPSG","8901"]],UNIT["degree",0.0174532925199433,'
        'AUTHORITY["EPSG","9122"]],AUTHORITY["EPSG","4326"]],PROJECTION["Transverse_Mercator"],'
        f'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",{6 * zone - 183}],'
        'PARAMETER["scale_factor",0.9996],PARAMETER["false_easting",500000],'
        f'PARAMETER["false_northing",{10000000 if south else 0}],UNIT["metre",1,AUTHORITY["EPSG","9001"]],'
        f'AXIS["Easting",EAST],AXIS["Northing",NORTH],AUTHORITY["EPSG","{code}"]]'
    )


def _crs_from_wkt(wkt: str) -> str | None:
    """``"EPSG:n"`` from the outermost node's own authority of a WKT string (WKT1 ``AUTHORITY`` or
    WKT2 ``ID``, wherever it stands among that node's children), else the stripped WKT, else None."""
    text = wkt.strip().rstrip("\0").strip()
    if not text:
        return None
    depth = 0
    in_quote = False
    for i, ch in enumerate(text):
        if ch == '"':
            in_quote = not in_quote
        elif in_quote:
            continue
        elif ch in "[(":
            depth += 1
        elif ch in "])":
            depth -= 1
        elif depth == 1 and ch in "AIai" and (i == 0 or text[i - 1] in ", "):
            m = _EPSG_NODE.match(text, i)
            if m:
                return f"EPSG:{int(m.group(1))}"
    return text


def _crs_from_geokeys(vlr: GeoKeyDirectoryVlr) -> str | None:
    """``"EPSG:n"`` from a GeoTIFF key directory (projected key preferred), else None."""
    found: dict[int, int] = {}
    for key in vlr.geo_keys:
        if key.id in (_PROJECTED_KEY, _GEOGRAPHIC_KEY) and key.tiff_tag_location == 0:
            if 1024 <= key.value_offset <= 32766:
                found[key.id] = int(key.value_offset)
    code = found.get(_PROJECTED_KEY, found.get(_GEOGRAPHIC_KEY))
    return f"EPSG:{code}" if code is not None else None


def _read_crs(las: laspy.LasData) -> str | None:
    """CRS string of a LAS file (see the module docstring for the order), or None."""
    try:
        import pyproj  # noqa: F401
    except ImportError:
        pass
    else:
        try:
            parsed = las.header.parse_crs()
        except Exception:  # malformed records: fall back to the manual parse below
            parsed = None
        if parsed is not None:
            auth = parsed.to_authority()
            return f"{auth[0]}:{auth[1]}" if auth else parsed.to_wkt()
    vlrs = list(las.header.vlrs) + list(las.evlrs or [])
    for vlr in vlrs:
        if isinstance(vlr, WktCoordinateSystemVlr):
            crs = _crs_from_wkt(vlr.string)
            if crs:
                return crs
    for vlr in vlrs:
        if isinstance(vlr, GeoKeyDirectoryVlr):
            crs = _crs_from_geokeys(vlr)
            if crs:
                return crs
    for vlr in vlrs:
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
    """Attach ``crs`` to ``header`` (see the module docstring)."""
    try:
        import pyproj
    except ImportError:
        pyproj = None
    if pyproj is not None:
        try:
            header.add_crs(pyproj.CRS.from_user_input(crs))
            return
        except pyproj.exceptions.CRSError as exc:
            raise PointCloudError(f"{where}: pyproj does not understand crs={crs!r} ({exc}); fix the CRS string") from exc
    wkt = utm_wkt(crs)
    if wkt is None and crs.lstrip().upper().startswith(_WKT_HEADS):
        wkt = crs
    if wkt is not None:
        header.vlrs.append(WktCoordinateSystemVlr(wkt))
        header.global_encoding.wkt = True
        return
    warnings.warn(
        f"{where}: CRS {crs!r} stored only in a 'sonardet' VLR (other tools will not see it); "
        "install pyproj to write a standard WKT record",
        stacklevel=4,
    )
    header.vlrs.append(laspy.VLR(SONARDET_VLR_USER, _VLR_CRS, "crs", crs.encode("utf-8")))


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


def write(path: str | Path, cloud: PointCloud, *, las_scale_m: float = 0.001) -> None:
    """Write ``cloud`` as LAS 1.4 point format 6 (``.laz``: compressed), atomically.

    Coordinates (metres, the cloud's frame) are quantised to ``las_scale_m`` metres (default 1 mm),
    offsets at the data minimum floored to a whole metre. See the module docstring for attributes and CRS.
    """
    p = Path(path)
    where = str(p)
    scale_m = las_scale_m
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise PointCloudError(f"{where}: las_scale_m must be a positive number of metres, got {scale_m!r}")
    xyz = cloud.xyz
    offsets = np.floor(xyz.min(axis=0))
    span = float((xyz.max(axis=0) - offsets).max())
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

    standard = {d.name: d for d in header.point_format.dimensions if d.name not in ("X", "Y", "Z")}
    to_standard: dict[str, np.ndarray] = {}
    to_extra: dict[str, np.ndarray] = {}
    for name, values in cloud.attributes.items():
        if name in standard:
            to_standard[name] = _fit_standard(values, standard[name], where)
        else:
            if len(name.encode("utf-8")) > 32:
                raise PointCloudError(f"{where}: attribute name {name!r} is longer than LAS's 32 bytes; rename it")
            if name.lower() in (s.lower() for s in standard) or name in ("X", "Y", "Z"):
                raise PointCloudError(f"{where}: attribute {name!r} clashes with a LAS field name; rename it")
            arr = values.astype(np.uint8) if values.dtype.kind == "b" else values
            to_extra[name] = arr
    if to_extra:
        header.add_extra_dims([laspy.ExtraBytesParams(name=k, type=v.dtype) for k, v in to_extra.items()])
    if cloud.crs is not None:
        _add_crs(header, cloud.crs, where)
    if cloud.origin is not None:
        header.vlrs.append(
            laspy.VLR(SONARDET_VLR_USER, _VLR_ORIGIN, "local origin x y z (m)", struct.pack("<3d", *cloud.origin))
        )

    las = laspy.LasData(header)
    las.x = xyz[:, 0]
    las.y = xyz[:, 1]
    las.z = xyz[:, 2]
    for name in ("return_number", "number_of_returns"):
        if name not in to_standard:
            las[name] = np.ones(len(cloud), dtype=np.uint8)
    for name, values in {**to_standard, **to_extra}.items():
        las[name] = values
    compress = p.name.lower().endswith(".laz")
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        las.write(fh, do_compress=compress)


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
