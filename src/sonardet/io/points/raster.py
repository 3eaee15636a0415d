"""Gridded bathymetry as soundings: GeoTIFF (``.tif``, ``.tiff``) and BAG (``.bag``, the Bathymetric
Attributed Grid of ONS/IHO) through rasterio (GDAL).

Every grid node that holds a value becomes one sounding at the node's cell centre: x, y from the
raster's affine transform (rotated or sheared grids included), z from band 1. Nodes equal to the band's
nodata value, masked by GDAL, or NaN/Inf are dropped. Further bands become attributes named after the
band description (BAG: ``uncertainty``), else ``band2``, ``band3``, ... (whole-file reads only).

Vertical direction: a BAG's elevation band is positive up by the format's definition; a GeoTIFF band
may hold elevations or depths, so it is read as elevation unless ``z_positive="down"``, and the checks of
``core.apply_z_positive`` apply (mostly positive values: a warning naming ``--z-positive down``).

CRS: the raster's own (GeoTIFF keys or the BAG's metadata), as a ``sonardet.io.crs.crs_string``; a
raster without one is refused unless ``crs=`` (``--crs``) gives it; one contradicting ``crs=`` is refused.
:func:`cell_size_m` gives the node spacing in metres (geodesic for geographic rasters), which the survey
layer checks against the objects' size.

Rasters are read only; :func:`write` refuses (write soundings as LAS/LAZ, PLY, NPZ or text).
Chunked reading (:func:`iter_chunks`) reads whole rows of the raster at a time (``chunk_points`` nodes
per chunk, at least one row), so memory is bounded by the chunk.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sonardet.io.crs import crs_string, horizontal_crs, parse_crs
from sonardet.io.points.core import (
    DEFAULT_CHUNK_POINTS,
    PointCloud,
    PointCloudError,
    apply_z_positive,
    check_z_positive,
    merge_crs,
)

__all__ = ["NAME", "SUFFIXES", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS", "cell_size_m", "iter_chunks", "read",
           "write"]

#: Format key (``sonardet.io.points.point_format``).
NAME = "raster"
#: File suffixes of this format.
SUFFIXES: tuple[str, ...] = (".tif", ".tiff", ".bag")
#: Whether :func:`iter_chunks` reads the file chunk by chunk.
STREAMED = True
#: Keywords of ``read_points`` this format takes.
READ_OPTIONS: tuple[str, ...] = ("z_positive",)
WRITE_OPTIONS: tuple[str, ...] = ()


def _open(path: Path):
    """The rasterio dataset of `path`; an unreadable file raises PointCloudError naming it."""
    import rasterio

    try:
        return rasterio.open(path)
    except rasterio.errors.RasterioIOError as exc:
        raise PointCloudError(f"{path}: not a readable GeoTIFF/BAG raster ({exc})") from None


def _crs(ds, crs: str | None, where: str) -> str:
    """The raster's CRS string (the file's, or ``crs`` when it has none); none at all raises."""
    found = crs_string(parse_crs(ds.crs.to_wkt(), where)) if ds.crs else None
    if found is None and crs is None:
        raise PointCloudError(f"{where}: the raster carries no CRS (no georeferencing keys); give the CRS of its "
                              "coordinates with --crs (e.g. EPSG:32610), or write it into the file (gdal_edit.py "
                              "-a_srs)")
    return merge_crs(found, crs, where)


def _is_bag(path: Path) -> bool:
    return path.name.lower().endswith(".bag")


def cell_size_m(path: str | Path, crs: str | None = None) -> float:
    """The larger node spacing of a raster (m): the lengths of the affine transform's column and row
    steps, converted from degrees with the WGS 84 ellipsoid at the raster's centre (pyproj.Geod) when its
    CRS is geographic. ``crs``: the CRS when the file has none."""
    p = Path(path)
    with _open(p) as ds:
        t = ds.transform
        steps = (float(np.hypot(t.a, t.d)), float(np.hypot(t.b, t.e)))
        geo = horizontal_crs(parse_crs(_crs(ds, crs, str(p)), str(p)))
        if not geo.is_geographic:
            return max(steps) * float(geo.axis_info[0].unit_conversion_factor)
        import pyproj

        def node(col: float, row: float) -> tuple[float, float]:
            return t.a * col + t.b * row + t.c, t.d * col + t.e * row + t.f

        lon0, lat0 = node(ds.width / 2.0, ds.height / 2.0)
        geod = pyproj.Geod(ellps="WGS84")
        ends = (node(ds.width / 2.0 + 1, ds.height / 2.0), node(ds.width / 2.0, ds.height / 2.0 + 1))
        return max(float(geod.inv(lon0, lat0, lon, lat)[2]) for lon, lat in ends)


def _nodes(ds, row0: int, rows: int, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xyz of the kept nodes (n, 3), keep mask, band-1 values) of `rows` raster rows from `row0`: x, y
    the cell centres in the raster's CRS, z band 1 as stored; masked (nodata) and NaN/Inf nodes dropped."""
    from rasterio.windows import Window

    band = ds.read(1, window=Window(0, row0, ds.width, rows), masked=True)
    values = np.ma.filled(band.astype(np.float64), np.nan).ravel()
    keep = np.isfinite(values)
    cols, rws = np.meshgrid(np.arange(ds.width, dtype=np.float64) + 0.5,
                            np.arange(row0, row0 + rows, dtype=np.float64) + 0.5)
    t = ds.transform
    x = t.a * cols.ravel() + t.b * rws.ravel() + t.c
    y = t.d * cols.ravel() + t.e * rws.ravel() + t.f
    return np.stack([x[keep], y[keep], values[keep]], axis=1), keep, values


def _attribute_name(ds, band: int) -> str:
    """Attribute name of raster band `band` (1-based): its description normalised, else band{band}."""
    desc = (ds.descriptions[band - 1] or "").strip().lower()
    name = re.sub(r"[^a-z0-9_]+", "_", desc).strip("_")
    return name if name and name not in ("x", "y", "z", "xyz", "origin", "crs") else f"band{band}"


def read(path: str | Path, *, crs: str | None = None, z_positive: str | None = None) -> PointCloud:
    """Read a GeoTIFF or BAG as soundings (see the module doc): xyz float64 (x, y in the raster's CRS, z
    m up), further bands as attributes, the raster's CRS (or ``crs``)."""
    p = Path(path)
    where = str(p)
    check_z_positive(z_positive, where)
    with _open(p) as ds:
        cloud_crs = _crs(ds, crs, where)
        xyz, keep, _ = _nodes(ds, 0, ds.height, where)
        attrs = {}
        for band in range(2, ds.count + 1):
            values = ds.read(band).astype(np.float64).ravel()[keep]
            attrs[_attribute_name(ds, band)] = values
    if not len(xyz):
        raise PointCloudError(f"{where}: no points (every grid node is nodata)")
    down = z_positive == "down"
    apply_z_positive(xyz[:, 2], down, ambiguous=not _is_bag(p), explicit=z_positive is not None, where=where)
    return PointCloud(xyz, attrs, crs=cloud_crs, source=where)


def iter_chunks(path: str | Path, *, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS,
                z_positive: str | None = None) -> Iterator[PointCloud]:
    """The raster's soundings (as :func:`read`, x, y, z only) in chunks of whole rows, at most
    ``chunk_points`` nodes each (at least one row), top row first; the vertical checks look at the
    first non-empty chunk."""
    p = Path(path)
    where = str(p)
    check_z_positive(z_positive, where)
    n = 0
    with _open(p) as ds:
        cloud_crs = _crs(ds, crs, where)
        step = max(1, int(chunk_points) // max(1, ds.width))
        for row0 in range(0, ds.height, step):
            xyz, _, _ = _nodes(ds, row0, min(step, ds.height - row0), where)
            if not len(xyz):
                continue
            if n == 0:
                apply_z_positive(xyz[:, 2], z_positive == "down", ambiguous=not _is_bag(p),
                                 explicit=z_positive is not None, where=where)
            elif z_positive == "down":
                np.negative(xyz[:, 2], out=xyz[:, 2])
            n += len(xyz)
            yield PointCloud(xyz, crs=cloud_crs, source=where)
    if n == 0:
        raise PointCloudError(f"{where}: no points (every grid node is nodata)")


def write(path: str | Path, cloud: PointCloud) -> None:
    """Rasters are read only: always raises PointCloudError (write soundings as .las/.laz, .ply, .npz or
    text)."""
    raise PointCloudError(f"{path}: GeoTIFF/BAG are read only here; write the soundings as .las, .laz, .ply, .npz "
                          "or .xyz")
