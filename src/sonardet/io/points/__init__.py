"""Point-cloud readers and writers with float64 georeferenced coordinates.

One entry point each way, :func:`read_points` and :func:`write_points`, and one chunked reader,
:func:`iter_chunks`; each looks the file suffix up in :data:`FORMAT_TABLE` and hands the file to that
format's module (the pattern of Open3D's ``read_point_cloud``):

=====================================  =====================================================  ==========
suffix                                 format                                                 chunks
=====================================  =====================================================  ==========
``.xyz .txt .pts .csv`` (+ ``.gz``)    text, whitespace- or comma-separated (``text.py``)     streamed
``.las .laz``                          LAS 1.4 / LAZ through laspy (``las.py``)               streamed
``.ply``                               PLY, ascii or binary (``ply.py``)                      whole file
``.npz``                               the scene format of DESIGN.md (``npz.py``)             whole file
``.tif .tiff .bag``                    gridded bathymetry, GeoTIFF / BAG (``raster.py``),     rows
                                       read only: grid nodes become soundings
=====================================  =====================================================  ==========

A format module exports ``NAME``, ``SUFFIXES``, ``STREAMED``, ``READ_OPTIONS`` and ``WRITE_OPTIONS``
(the keywords of :func:`read_points` / :func:`write_points` it takes) and
``read(path, *, crs=None, **options) -> PointCloud``, ``write(path, cloud, **options)`` and
``iter_chunks(path, *, crs=None, chunk_points=...)``. Chunks are :class:`PointCloud` objects holding x,
y, z only (no attributes), with the file's CRS and origin; their rows, concatenated, are the ``xyz``
of :func:`read_points`, value for value.

Vertical direction: z is up. ``z_positive="down"`` (``--z-positive down``) reads a text or GeoTIFF file's
vertical values as depths (z = -value); a ``depth`` column is positive down by its name. The checks
of ``core.apply_z_positive`` refuse depths that are elevations already and warn about a headerless file
that looks positive down.

Coordinates are always float64 metres in the file's own frame (the CRS's, e.g. EPSG:32610 easting,
northing, elevation). Move them to a local frame (``PointCloud.local``,
``sonardet.io.origin.LocalFrame``) before any float32 work.

Writes are atomic (``sonardet.io.atomic.atomic_path``): the data go to a temporary file in the target
directory, which replaces the target with ``os.replace`` only once complete; on any error the
temporary file is removed and an existing target is left untouched. Outputs are deterministic (gzip and
zip time stamps are fixed; LAS takes its creation date from ``SOURCE_DATE_EPOCH`` when set).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType

from sonardet.io.points import las, npz, ply, raster, text
from sonardet.io.points.core import (
    DEFAULT_CHUNK_POINTS,
    RESERVED_NAMES,
    Z_POSITIVE,
    PointCloud,
    PointCloudError,
    UnsupportedFormatError,
    check_finite,
    check_plausible,
    iter_slices,
    merge_crs,
    normalize_crs,
)

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "FORMAT_TABLE",
    "RESERVED_NAMES",
    "SUPPORTED_SUFFIXES",
    "TEXT_SUFFIXES",
    "PointCloud",
    "PointCloudError",
    "UnsupportedFormatError",
    "Z_POSITIVE",
    "check_finite",
    "check_plausible",
    "format_module",
    "grid_cell_m",
    "iter_chunks",
    "iter_slices",
    "merge_crs",
    "normalize_crs",
    "point_format",
    "read_points",
    "write_points",
]

#: The format table: file suffix (lower case) -> the module that reads and writes that format.
FORMAT_TABLE: dict[str, ModuleType] = {suffix: module for module in (text, las, ply, npz, raster)
                                     for suffix in module.SUFFIXES}
#: Plain-text suffixes; each may also end in ``.gz``.
TEXT_SUFFIXES: tuple[str, ...] = text.BASE_SUFFIXES
#: Every suffix :func:`read_points` and :func:`write_points` accept.
SUPPORTED_SUFFIXES: tuple[str, ...] = tuple(FORMAT_TABLE)


def format_module(path: str | os.PathLike) -> ModuleType:
    """The format module of ``path`` (:data:`FORMAT_TABLE`), from its suffix, case-insensitively; the
    longest matching suffix wins (``.xyz.gz`` over ``.gz``).

    Raises :class:`UnsupportedFormatError` listing the supported suffixes.
    """
    name = Path(path).name.lower()
    for suffix in sorted(SUPPORTED_SUFFIXES, key=len, reverse=True):
        if name.endswith(suffix) and len(name) > len(suffix):
            return FORMAT_TABLE[suffix]
    raise UnsupportedFormatError(
        f"{path}: unsupported point-cloud suffix; supported: {', '.join(SUPPORTED_SUFFIXES)}"
    )


def point_format(path: str | os.PathLike) -> str:
    """Format key of ``path`` from its suffix: 'text', 'las', 'ply', 'npz' or 'raster'.

    Raises :class:`UnsupportedFormatError` listing the supported suffixes.
    """
    return format_module(path).NAME


def _existing_file(path: str | os.PathLike) -> tuple[Path, ModuleType]:
    """(path, format module) of a point-cloud file that exists; raise otherwise."""
    p = Path(path)
    module = format_module(p)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such point-cloud file")
    if p.is_dir():
        raise PointCloudError(f"{p}: is a directory, expected a point-cloud file")
    return p, module


def _options(p: Path, module: ModuleType, columns, z_positive) -> dict:
    """The reading options of ``read_points``/``iter_chunks`` that ``module`` takes; one it does not take
    but that was given raises PointCloudError."""
    given = {"columns": columns, "z_positive": z_positive}
    unused = [k for k, v in given.items() if v is not None and k not in module.READ_OPTIONS]
    if unused:
        raise PointCloudError(f"{p}: {', '.join(unused)} (--{unused[0].replace('_', '-')}) do(es) not apply to "
                              f"{module.NAME} files")
    return {k: v for k, v in given.items() if k in module.READ_OPTIONS}


def read_points(
    path: str | os.PathLike,
    *,
    columns: Sequence[str] | None = None,
    crs: str | None = None,
    z_positive: str | None = None,
) -> PointCloud:
    """Read a point cloud; coordinates float64 in the file's frame (metres; degrees for longitude/latitude
    text columns), z up.

    Args:
        path: file with one of :data:`SUPPORTED_SUFFIXES` (case-insensitive).
        columns: text files only: names of the columns in file order, replacing the header (or
            naming the columns of a headerless file). Names map to x/y/z as documented in
            ``sonardet.io.points.text``.
        crs: CRS of the coordinates (``"EPSG:32610"``) when the file carries none (text files
            never do). If the file declares a different CRS, a ``PointCloudError`` is raised.
        z_positive: text and GeoTIFF files: ``"up"`` (elevations) or ``"down"`` (depths, read as
            z = -value); None: from the column name (``depth`` is down), else up, with the checks of
            ``core.apply_z_positive``.

    Returns:
        :class:`PointCloud` with ``source=str(path)``.

    Raises:
        FileNotFoundError; :class:`UnsupportedFormatError`; :class:`PointCloudError` for an empty
        file ("no points"), wrong column counts (with the 1-based line), non-numeric values,
        NaN/Inf coordinates (with the row), bad fields, depths that are elevations;
        :class:`sonardet.io.origin.GlobalCoordinatesError` (also a ``ValueError``) for a PLY or NPZ
        file that stores UTM-magnitude coordinates in float32.
    """
    p, module = _existing_file(path)
    return module.read(p, crs=crs, **_options(p, module, columns, z_positive))


def grid_cell_m(path: str | os.PathLike, crs: str | None = None) -> float | None:
    """Node spacing (m) of a gridded file (GeoTIFF, BAG: ``raster.cell_size_m``); None for point formats."""
    p, module = _existing_file(path)
    return module.cell_size_m(p, crs) if module is raster else None


def write_points(
    path: str | os.PathLike,
    cloud: PointCloud,
    *,
    header: bool | None = None,
    decimals: int | None = None,
    las_scale_m: float = 0.001,
    compress: bool = True,
) -> Path:
    """Write ``cloud`` atomically in the format given by the suffix of ``path``; return the path.

    Args:
        header: text only: write a header line of column names. Default: for ``.csv`` and for any
            text file whose cloud has attributes (so their names survive); never for ``.pts``.
        decimals: text only: fixed decimals for floats (3 = mm). Default None writes the shortest
            repr that reads back to the identical float64.
        las_scale_m: LAS/LAZ only: coordinate resolution (metres); offsets are the data minimum
            floored to a whole metre.
        compress: NPZ only: deflate the arrays (``np.savez_compressed`` equivalent).

    Options of other formats are ignored. What each format keeps: text keeps xyz and attributes (no
    CRS, no origin); LAS keeps xyz to ``las_scale_m``, attributes, CRS and origin; PLY and NPZ keep
    everything bit-exactly. Raises :class:`PointCloudError` for an empty cloud or values a format
    cannot hold.
    """
    p = Path(path)
    module = format_module(p)
    if not isinstance(cloud, PointCloud):
        raise TypeError(f"write_points: expected a PointCloud, got {type(cloud).__name__}")
    if not len(cloud):
        raise PointCloudError(f"{p}: the cloud has no points; refusing to write an empty point file")
    given = {"header": header, "decimals": decimals, "las_scale_m": las_scale_m, "compress": compress}
    module.write(p, cloud, **{k: v for k, v in given.items() if k in module.WRITE_OPTIONS})
    return p


def iter_chunks(
    path: str | os.PathLike, *, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS,
    columns: Sequence[str] | None = None, z_positive: str | None = None,
) -> Iterator[PointCloud]:
    """Read a point cloud chunk by chunk: :class:`PointCloud` objects of at most ``chunk_points`` points
    holding x, y, z only (float64 metres, the file's frame; no attributes) with the file's CRS and
    origin, in file order; concatenated, their coordinates are those of :func:`read_points` (``columns``
    and ``z_positive`` as there).

    Text and LAS/LAZ files are streamed (memory: one chunk); PLY and NPZ files are read whole and sliced
    (the format module's ``STREAMED``). ``crs`` as in :func:`read_points`. The path, suffix and
    ``chunk_points`` (>= 1) are checked here, the file's content as the chunks are read: a bad line in a
    later chunk raises there, with the message :func:`read_points` gives.

    Raises FileNotFoundError, :class:`UnsupportedFormatError`, ValueError for ``chunk_points`` < 1, and
    :class:`PointCloudError` as :func:`read_points` does.
    """
    p, module = _existing_file(path)
    if int(chunk_points) < 1:
        raise ValueError(f"chunk_points must be >= 1, got {chunk_points!r}")
    return module.iter_chunks(p, crs=crs, chunk_points=int(chunk_points), **_options(p, module, columns, z_positive))
