"""Point-cloud readers and writers with float64 georeferenced coordinates.

One entry point each way: :func:`read_points` and :func:`write_points` dispatch on the file suffix.

=====================================  ===========================================================
suffix                                 format
=====================================  ===========================================================
``.xyz .txt .pts .csv`` (+ ``.gz``)    text, whitespace- or comma-separated (see ``text.py``)
``.las .laz``                          LAS 1.4 / LAZ through laspy (see ``las.py``)
``.ply``                               PLY, ascii or binary (see ``ply.py``)
``.npz``                               the scene format of DESIGN.md (this module)
=====================================  ===========================================================

Coordinates are always float64 metres in the file's own frame (the CRS's, e.g. EPSG:32610 easting,
northing, elevation). Move them to a local frame (``PointCloud.local``,
``sonardet.io.origin.LocalFrame``) before any float32 work.

NPZ scene format (DESIGN.md §3): ``xyz`` (N, 3) float64; any number of per-point 1-D arrays of
length N (``ping``, ``beam``, ``line``, ``label``, ...), which become ``PointCloud.attributes``;
optional ``origin`` (3,) float64, the local frame's origin in the frame of ``xyz`` (so
``local = xyz - origin``; ``xyz`` itself is stored as is, never pre-shifted); optional ``crs``, a
0-d string array. Any other entry is an error (nothing is silently dropped).

Writes are atomic (``sonardet.io.atomic.atomic_path``): the data go to a temporary file in the target
directory, which replaces the target with ``os.replace`` only once complete; on any error the
temporary file is removed and an existing target is left untouched. Outputs are deterministic (gzip and zip time stamps are fixed; LAS takes
its creation date from ``SOURCE_DATE_EPOCH`` when set).
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from sonardet.io.atomic import atomic_path  # shared helper: temp file in the target dir + os.replace
from sonardet.io.origin import LOCAL_LIMIT_M, GlobalCoordinatesError, LocalFrame, choose_origin

__all__ = [
    "PointCloud",
    "PointCloudError",
    "UnsupportedFormatError",
    "SUPPORTED_SUFFIXES",
    "TEXT_SUFFIXES",
    "read_points",
    "write_points",
    "read_npz",
    "write_npz",
    "point_format",
    "normalize_crs",
]

#: Plain-text suffixes; each may also end in ``.gz``.
TEXT_SUFFIXES: tuple[str, ...] = (".xyz", ".txt", ".pts", ".csv")
#: Every suffix :func:`read_points` and :func:`write_points` accept.
SUPPORTED_SUFFIXES: tuple[str, ...] = (
    *TEXT_SUFFIXES,
    *(s + ".gz" for s in TEXT_SUFFIXES),
    ".las",
    ".laz",
    ".ply",
    ".npz",
)
#: Attribute names that would clash with coordinates or metadata entries.
RESERVED_NAMES = frozenset({"x", "y", "z", "xyz", "origin", "crs"})


class PointCloudError(ValueError):
    """A point-cloud file or object is invalid; the message names the file, line/field and fix."""


class UnsupportedFormatError(PointCloudError):
    """The file suffix is not one :func:`read_points`/:func:`write_points` handles."""


def _label(source: str | os.PathLike | None) -> str:
    """Short name of a source for messages."""
    return str(source) if source is not None else "<PointCloud>"


@dataclass(eq=False)
class PointCloud:
    """Points with per-point attributes.

    Attributes:
        xyz: float64 (N, 3) coordinates in metres in the file's frame (the CRS's, e.g. UTM
            easting, northing, elevation). Never float32: float32 input is upcast when its values
            are local (|v| <= 1e5 m) and refused when they are global (precision already lost).
        attributes: name -> 1-D array of length N (``ping``, ``beam``, ``line``, ``label``,
            ``intensity``, ...), dtype as read.
        crs: CRS of ``xyz`` as a string (``"EPSG:32610"``, or WKT when no EPSG code is known), or
            None when unknown.
        source: the path the cloud was read from (for messages), or None.
        origin: optional float64 (3,) local-frame origin in the frame of ``xyz`` (metres); None
            lets :meth:`frame` choose one with :func:`sonardet.io.origin.choose_origin`.

    Arrays are validated on construction (shape, dtype, NaN/Inf, lengths); they are not copied
    unless a dtype conversion is needed.
    """

    xyz: np.ndarray
    attributes: dict[str, np.ndarray] = field(default_factory=dict)
    crs: str | None = None
    source: str | None = None
    origin: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.source is not None:
            self.source = str(self.source)
        where = _label(self.source)
        xyz = np.asarray(self.xyz)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise PointCloudError(f"{where}: field 'xyz' must have shape (N, 3), got {xyz.shape}")
        if xyz.dtype.kind not in "fiu":
            raise PointCloudError(f"{where}: field 'xyz' must be numeric, got dtype {xyz.dtype}")
        if xyz.dtype != np.float64:
            if xyz.dtype.kind == "f" and xyz.dtype.itemsize < 8 and xyz.size:
                peak = float(np.nanmax(np.abs(np.where(np.isfinite(xyz), xyz, 0))))
                if peak > LOCAL_LIMIT_M:
                    raise GlobalCoordinatesError(
                        f"{where}: field 'xyz' is {xyz.dtype} with |coordinate| up to {peak:.1f} m; at "
                        "this magnitude it resolves only 0.03-0.5 m. Keep global coordinates in float64 "
                        "(re-export the file with double precision)."
                    )
            xyz = xyz.astype(np.float64)
        self.xyz = np.ascontiguousarray(xyz)
        _check_finite(self.xyz, where)
        n = self.xyz.shape[0]

        if not isinstance(self.attributes, Mapping):
            raise PointCloudError(f"{where}: attributes must be a dict of name -> 1-D array")
        attrs: dict[str, np.ndarray] = {}
        for name, values in self.attributes.items():
            if not isinstance(name, str) or not name or name != name.strip():
                raise PointCloudError(f"{where}: attribute name {name!r} must be a non-empty string")
            if name.lower() in RESERVED_NAMES:
                raise PointCloudError(
                    f"{where}: attribute name {name!r} is reserved ({sorted(RESERVED_NAMES)}); rename it"
                )
            arr = np.asarray(values)
            if arr.ndim != 1 or arr.shape[0] != n:
                raise PointCloudError(
                    f"{where}: attribute {name!r} must be a 1-D array of {n} values (one per point), "
                    f"got shape {arr.shape}"
                )
            if arr.dtype.kind not in "biuf":
                raise PointCloudError(
                    f"{where}: attribute {name!r} must be numeric or boolean, got dtype {arr.dtype}"
                )
            attrs[name] = arr
        self.attributes = attrs

        if self.crs is not None:
            if not isinstance(self.crs, str) or not self.crs.strip():
                raise PointCloudError(f"{where}: crs must be a non-empty string such as 'EPSG:32610' or None")
            self.crs = normalize_crs(self.crs)
        if self.origin is not None:
            org = np.asarray(self.origin)
            if org.shape != (3,) or org.dtype.kind not in "fiu" or not np.all(np.isfinite(org)):
                raise PointCloudError(
                    f"{where}: origin must be 3 finite numbers (metres), got {np.asarray(self.origin)!r}"
                )
            self.origin = org.astype(np.float64)

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return int(self.xyz.shape[0])

    @property
    def n_points(self) -> int:
        """Number of points."""
        return int(self.xyz.shape[0])

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min, max) of ``xyz`` per axis, float64 metres in the file's frame."""
        if not len(self):
            raise PointCloudError(f"{_label(self.source)}: no points; bounds are undefined")
        return self.xyz.min(axis=0), self.xyz.max(axis=0)

    def frame(self, *, round_m: float = 1.0) -> LocalFrame:
        """The local frame: ``self.origin`` if set, else the origin ``choose_origin`` picks.

        The choice is deterministic, so repeated calls give the same frame; store it (e.g.
        ``frame.to_dict()`` in a results JSON) to shift results back with ``frame.to_global``.
        """
        if self.origin is not None:
            return LocalFrame(self.origin, self.crs)
        if not len(self):
            raise PointCloudError(f"{_label(self.source)}: no points; cannot choose a local origin")
        return LocalFrame(choose_origin(self.xyz, round_m=round_m), self.crs)

    def local(self, dtype: DTypeLike = np.float64, *, frame: LocalFrame | None = None) -> np.ndarray:
        """Coordinates in the local frame (``xyz - origin``, metres), cast to ``dtype`` after the shift.

        This is the way to get float32 coordinates: ``cloud.local(np.float32)``. ``frame`` defaults
        to :meth:`frame`. Raises ``GlobalCoordinatesError`` if the shifted values still exceed 1e5 m.
        """
        return (frame or self.frame()).to_local(self.xyz, dtype=dtype)

    def select(self, index: ArrayLike) -> PointCloud:
        """A new cloud with the points picked by ``index`` (boolean mask or integer indices)."""
        idx = np.asarray(index)
        return PointCloud(
            self.xyz[idx],
            {k: v[idx] for k, v in self.attributes.items()},
            crs=self.crs,
            source=self.source,
            origin=self.origin,
        )


def _check_finite(xyz: np.ndarray, where: str, line_of_row: Sequence[int] | None = None) -> None:
    """Raise naming the first row (and text line) whose coordinates are NaN or Inf."""
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        row = int(np.argmax(bad))
        count = int(bad.sum())
        at = f"line {line_of_row[row]} (point {row})" if line_of_row is not None else f"point {row} (0-based)"
        raise PointCloudError(
            f"{where} {at}: non-finite coordinates x, y, z = {xyz[row].tolist()} "
            f"({count} point(s) affected); remove or fix those points before reading"
        )


def normalize_crs(crs: str) -> str:
    """Canonical spelling of a CRS string: ``epsg:32610`` / ``EPSG: 32610`` -> ``EPSG:32610``."""
    text = crs.strip()
    head, sep, tail = text.partition(":")
    if sep and head.strip().upper() == "EPSG" and tail.strip().isdigit():
        return f"EPSG:{int(tail.strip())}"
    return text


def _merge_crs(found: str | None, given: str | None, where: str) -> str | None:
    """Combine the file's CRS with the caller's ``crs=``; refuse a contradiction."""
    if given is None:
        return found
    given = normalize_crs(given)
    if found is None or normalize_crs(found) == given:
        return given
    raise PointCloudError(
        f"{where}: the file declares CRS {found!r} but crs={given!r} was passed; pass crs=None to use "
        "the file's CRS, or rewrite the file with the correct one"
    )


# ---------------------------------------------------------------------------- dispatch
def point_format(path: str | os.PathLike) -> str:
    """Format key of ``path`` from its suffix: 'text', 'las', 'ply' or 'npz'.

    Raises :class:`UnsupportedFormatError` listing the supported suffixes.
    """
    name = Path(path).name.lower()
    for suffix in sorted(SUPPORTED_SUFFIXES, key=len, reverse=True):
        if name.endswith(suffix) and len(name) > len(suffix):
            if suffix in (".las", ".laz"):
                return "las"
            if suffix == ".ply":
                return "ply"
            if suffix == ".npz":
                return "npz"
            return "text"
    raise UnsupportedFormatError(
        f"{path}: unsupported point-cloud suffix; supported: {', '.join(SUPPORTED_SUFFIXES)}"
    )


def read_points(
    path: str | os.PathLike,
    *,
    columns: Sequence[str] | None = None,
    crs: str | None = None,
    depth_to_z: bool = False,
) -> PointCloud:
    """Read a point cloud; coordinates float64 metres in the file's frame.

    Args:
        path: file with one of :data:`SUPPORTED_SUFFIXES` (case-insensitive).
        columns: text files only: names of the columns in file order, replacing the header (or
            naming the columns of a headerless file). Names map to x/y/z as documented in
            ``sonardet.io.text``.
        crs: CRS of the coordinates (``"EPSG:32610"``) when the file carries none (text files
            never do). If the file declares a different CRS, a ``PointCloudError`` is raised.
        depth_to_z: text files only: allow a ``depth`` column (positive down) as the vertical
            coordinate, read as ``z = -depth``, when no elevation column exists. Without it such a
            file is refused rather than guessed.

    Returns:
        :class:`PointCloud` with ``source=str(path)``.

    Raises:
        FileNotFoundError; :class:`UnsupportedFormatError`; :class:`PointCloudError` for an empty
        file ("no points"), wrong column counts (with the 1-based line), non-numeric values,
        NaN/Inf coordinates (with the row), bad fields;
        :class:`sonardet.io.origin.GlobalCoordinatesError` (also a ``ValueError``) for a PLY or NPZ
        file that stores UTM-magnitude coordinates in float32.
    """
    p = Path(path)
    fmt = point_format(p)
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such point-cloud file")
    if p.is_dir():
        raise PointCloudError(f"{p}: is a directory, expected a point-cloud file")
    if fmt != "text" and (columns is not None or depth_to_z):
        raise PointCloudError(f"{p}: columns= and depth_to_z= apply to text files only, not {fmt}")
    if fmt == "text":
        from sonardet.io import text

        return text.read_text(p, columns=columns, crs=crs, depth_to_z=depth_to_z)
    if fmt == "las":
        from sonardet.io import las

        return las.read_las(p, crs=crs)
    if fmt == "ply":
        from sonardet.io import ply

        return ply.read_ply(p, crs=crs)
    return read_npz(p, crs=crs)


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

    What each format keeps: text keeps xyz and attributes (no CRS, no origin); LAS keeps xyz to
    ``las_scale_m``, attributes, CRS and origin; PLY and NPZ keep everything bit-exactly.
    Raises :class:`PointCloudError` for an empty cloud or values a format cannot hold.
    """
    p = Path(path)
    fmt = point_format(p)
    if not isinstance(cloud, PointCloud):
        raise TypeError(f"write_points: expected a PointCloud, got {type(cloud).__name__}")
    if not len(cloud):
        raise PointCloudError(f"{p}: the cloud has no points; refusing to write an empty point file")
    if fmt == "text":
        from sonardet.io import text

        text.write_text(p, cloud, header=header, decimals=decimals)
    elif fmt == "las":
        from sonardet.io import las

        las.write_las(p, cloud, scale_m=las_scale_m)
    elif fmt == "ply":
        from sonardet.io import ply

        ply.write_ply(p, cloud)
    else:
        write_npz(p, cloud, compress=compress)
    return p


# ---------------------------------------------------------------------------- npz
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def read_npz(path: str | os.PathLike, *, crs: str | None = None) -> PointCloud:
    """Read a DESIGN.md scene ``.npz`` (see module docstring); ``xyz`` float64 metres as stored."""
    p = Path(path)
    where = str(p)
    try:
        npz = np.load(p, allow_pickle=False)
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise PointCloudError(f"{where}: not a readable .npz archive ({exc}); rewrite it with write_points") from exc
    with npz:
        if not isinstance(npz, np.lib.npyio.NpzFile):
            raise PointCloudError(f"{where}: holds a single array, expected an .npz archive with 'xyz'")
        try:
            data = {k: npz[k] for k in npz.files}
        except ValueError as exc:  # object arrays need pickle, which is refused
            raise PointCloudError(f"{where}: an entry holds Python objects ({exc}); store plain arrays") from exc
    if "xyz" not in data:
        raise PointCloudError(
            f"{where}: no 'xyz' entry; a scene .npz needs 'xyz' float64 (N, 3) metres "
            f"(found entries: {sorted(data)})"
        )
    xyz = data.pop("xyz")
    if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.dtype.kind not in "fiu":
        raise PointCloudError(f"{where}: field 'xyz' must be a numeric (N, 3) array, got {xyz.dtype} {xyz.shape}")
    if xyz.shape[0] == 0:
        raise PointCloudError(f"{where}: no points ('xyz' has 0 rows)")
    n = xyz.shape[0]
    origin = data.pop("origin", None)
    if origin is not None and (origin.shape != (3,) or origin.dtype.kind not in "fiu"):
        raise PointCloudError(f"{where}: field 'origin' must be 3 numbers (metres), got {origin.dtype} {origin.shape}")
    file_crs = data.pop("crs", None)
    if file_crs is not None:
        if file_crs.size != 1 or file_crs.dtype.kind not in "US":
            raise PointCloudError(f"{where}: field 'crs' must be a 0-d string array, got {file_crs.dtype} {file_crs.shape}")
        value = file_crs.reshape(()).item()
        file_crs = (value.decode("utf-8") if isinstance(value, bytes) else str(value)).strip() or None
    attrs: dict[str, np.ndarray] = {}
    for name, arr in data.items():
        if arr.ndim != 1 or arr.shape[0] != n:
            raise PointCloudError(
                f"{where}: field {name!r} has shape {arr.shape}; per-point fields must be 1-D with {n} "
                "values (one per point of 'xyz'); drop or reshape it"
            )
        attrs[name] = arr
    return PointCloud(xyz, attrs, crs=_merge_crs(file_crs, crs, where), source=where, origin=origin)


def write_npz(path: str | os.PathLike, cloud: PointCloud, *, compress: bool = True) -> None:
    """Write ``cloud`` as a scene ``.npz`` (``np.load``-compatible, deterministic bytes, atomic)."""
    entries: dict[str, np.ndarray] = {"xyz": np.asarray(cloud.xyz, dtype=np.float64)}
    entries.update(cloud.attributes)
    if cloud.origin is not None:
        entries["origin"] = np.asarray(cloud.origin, dtype=np.float64)
    if cloud.crs is not None:
        entries["crs"] = np.array(cloud.crs)
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", compression=method) as zf:
        for name, arr in entries.items():
            info = zipfile.ZipInfo(name + ".npy", date_time=_ZIP_DATE)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with zf.open(info, "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asarray(arr, order="C"), allow_pickle=False)
