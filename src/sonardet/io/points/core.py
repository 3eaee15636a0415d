"""The point-cloud core: :class:`PointCloud`, the errors of the readers and writers, and the helpers the
format modules share (CRS spelling and merging, the finite-coordinates check, chunk slicing).

Coordinates are always float64 metres in the file's own frame (the CRS's, e.g. EPSG:32610 easting,
northing, elevation). Move them to a local frame (``PointCloud.local``,
``sonardet.io.origin.LocalFrame``) before any float32 work.

This module knows no file format; ``sonardet.io.points`` dispatches on the suffix to one module per
format (``text``, ``las``, ``ply``, ``npz``), each of which builds its clouds with the classes here.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from sonardet.io.origin import LOCAL_LIMIT_M, GlobalCoordinatesError, LocalFrame, choose_origin

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "MAX_DEPTH_M",
    "RESERVED_NAMES",
    "Z_POSITIVE",
    "PointCloud",
    "PointCloudError",
    "UnsupportedFormatError",
    "apply_z_positive",
    "check_finite",
    "check_plausible",
    "check_z_positive",
    "iter_slices",
    "merge_crs",
    "normalize_crs",
    "source_label",
]

#: Attribute names that would clash with coordinates or metadata entries.
RESERVED_NAMES = frozenset({"x", "y", "z", "xyz", "origin", "crs"})
#: Largest |x|, |y| (m) of a plausible survey coordinate in any projected CRS: UTM northings stay below
#: 1e7 m and eastings below 1e6 m, so 1e8 m is a value no survey holds (a unit or parsing error, a
#: sentinel such as 1e30).
PLAUSIBLE_XY_M = 1e8
#: Largest |z| (m) of a plausible sounding: the deepest ocean is 11 km deep, 1e5 m is beyond any survey.
PLAUSIBLE_Z_M = 1e5
#: Points per chunk of the chunked readers by default; 1e6 points of x y z text take about 48 MB.
DEFAULT_CHUNK_POINTS = 1_000_000


#: Accepted values of the ``z_positive`` option (``--z-positive``): which way the file's vertical values
#: point. ``up``: elevations (z); ``down``: depths, read as z = -depth.
Z_POSITIVE = ("up", "down")
#: Deepest sounding on Earth (m, rounded up): positive vertical values beyond it cannot be depths.
MAX_DEPTH_M = 11_000.0


class PointCloudError(ValueError):
    """A point-cloud file or object is invalid; the message names the file, line/field and fix."""


class UnsupportedFormatError(PointCloudError):
    """The file suffix is not one :func:`read_points`/:func:`write_points` handles."""


def source_label(source: str | os.PathLike | None) -> str:
    """Name of a point source for messages: the path as given, or ``<PointCloud>`` for none."""
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
        where = source_label(self.source)
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
        check_finite(self.xyz, where)
        check_plausible(self.xyz, where)
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
            raise PointCloudError(f"{source_label(self.source)}: no points; bounds are undefined")
        return self.xyz.min(axis=0), self.xyz.max(axis=0)

    def frame(self, *, round_m: float = 1.0) -> LocalFrame:
        """The local frame: ``self.origin`` if set, else the origin ``choose_origin`` picks.

        The choice is deterministic, so repeated calls give the same frame; store it (e.g.
        ``frame.to_dict()`` in a results JSON) to shift results back with ``frame.to_global``.
        """
        if self.origin is not None:
            return LocalFrame(self.origin, self.crs)
        if not len(self):
            raise PointCloudError(f"{source_label(self.source)}: no points; cannot choose a local origin")
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


def check_finite(xyz: np.ndarray, where: str, line_of_row: Sequence[int] | None = None) -> None:
    """Raise :class:`PointCloudError` naming the first row of ``xyz`` ((N, 3), any frame) whose coordinates
    are NaN or Inf, and how many rows are affected.

    ``where`` starts the message (the file); ``line_of_row`` maps a 0-based row to its 1-based line in a
    text file, so the message can name the line.
    """
    bad = ~np.isfinite(xyz).all(axis=1)
    if bad.any():
        row = int(np.argmax(bad))
        count = int(bad.sum())
        at = f"line {line_of_row[row]} (point {row})" if line_of_row is not None else f"point {row} (0-based)"
        raise PointCloudError(
            f"{where} {at}: non-finite coordinates x, y, z = {xyz[row].tolist()} "
            f"({count} point(s) affected); remove or fix those points before reading"
        )


def check_plausible(xyz: np.ndarray, where: str, line_of_row: Sequence[int] | None = None,
                    first_point: int = 0) -> None:
    """Raise :class:`PointCloudError` naming the first row of ``xyz`` ((N, 3) float64, metres, the file's
    frame) with a coordinate no survey can have: |x| or |y| > :data:`PLAUSIBLE_XY_M` or |z| >
    :data:`PLAUSIBLE_Z_M` (a sentinel such as 1e30, a unit or column mix-up), its value and how many rows
    are affected. Such a value would make tiling plan a grid over the whole bounding box.

    ``where`` starts the message (the file); ``line_of_row`` maps a 0-based row to its 1-based line in a
    text file; ``first_point`` is the index of row 0 in the file (a chunk of a larger file).
    """
    if not len(xyz):
        return
    bad = (np.abs(xyz[:, 0]) > PLAUSIBLE_XY_M) | (np.abs(xyz[:, 1]) > PLAUSIBLE_XY_M) | (np.abs(xyz[:, 2]) > PLAUSIBLE_Z_M)
    if bad.any():
        row = int(np.argmax(bad))
        point = first_point + row
        at = f"line {line_of_row[row]} (point {point})" if line_of_row is not None else f"point {point} (0-based)"
        raise PointCloudError(
            f"{where} {at}: implausible coordinates x, y, z = {xyz[row].tolist()} m ({int(bad.sum())} point(s) "
            f"beyond |x|, |y| <= {PLAUSIBLE_XY_M:g} m, |z| <= {PLAUSIBLE_Z_M:g} m); a sentinel value or a unit or "
            "column mix-up: remove or fix those points"
        )


def normalize_crs(crs: str) -> str:
    """Canonical spelling of a CRS string: ``epsg:32610`` / ``EPSG: 32610`` -> ``EPSG:32610``."""
    text = crs.strip()
    head, sep, tail = text.partition(":")
    if sep and head.strip().upper() == "EPSG" and tail.strip().isdigit():
        return f"EPSG:{int(tail.strip())}"
    return text


def merge_crs(found: str | None, given: str | None, where: str) -> str | None:
    """The CRS of a cloud from the one its file declares (``found``) and the one the caller passed
    (``given``, the readers' ``crs=``): ``given`` (normalised) when the file declares none or the same one,
    ``found`` when nothing was passed. A contradiction raises :class:`PointCloudError` naming ``where``.
    """
    if given is None:
        return found
    given = normalize_crs(given)
    if found is None or normalize_crs(found) == given:
        return given
    raise PointCloudError(
        f"{where}: the file declares CRS {found!r} but crs={given!r} was passed; pass crs=None to use "
        "the file's CRS, or rewrite the file with the correct one"
    )


def iter_slices(cloud: PointCloud, chunk_points: int) -> Iterator[PointCloud]:
    """Consecutive slices of ``cloud`` of at most ``chunk_points`` points, in order, as clouds holding x, y,
    z only (float64 metres, views of ``cloud.xyz``, no copy) with the cloud's CRS, origin and source.

    The chunked readers of the formats that have no streaming reader (PLY, NPZ) read the file whole and
    hand it on this way.
    """
    for a in range(0, len(cloud), chunk_points):
        yield PointCloud(cloud.xyz[a:a + chunk_points], crs=cloud.crs, source=cloud.source, origin=cloud.origin)


def check_z_positive(z_positive: str | None, where: str) -> None:
    """Raise :class:`PointCloudError` unless ``z_positive`` is None, ``"up"`` or ``"down"``."""
    if z_positive is not None and z_positive not in Z_POSITIVE:
        raise PointCloudError(f"{where}: z_positive (--z-positive) must be 'up' or 'down', got {z_positive!r}")


def apply_z_positive(values: np.ndarray, down: bool, *, ambiguous: bool, explicit: bool, where: str) -> np.ndarray:
    """Elevations (m, z up) from a file's vertical values ``values`` (float64, modified in place and
    returned): negated when ``down`` (depths, positive down).

    The rule for values that contradict their declared direction, applied to the values as read:

    * read as depths (``down``: a ``depth`` column or ``--z-positive down``) but more than half of them
      negative: they are elevations already (the seabed below the vertical reference has negative
      elevation and positive depth), and negating them would turn objects into pits. Raises
      :class:`PointCloudError` naming the file and ``--z-positive up``. (Drying heights above chart
      datum are negative depths too, but a survey of reef elements lies mostly below its datum.)
    * direction unknown (``ambiguous``: a headerless file or a plain ``z`` column, no ``--z-positive``)
      and more than half of the values positive, none beyond the deepest ocean (11 000 m): they look
      like depths; a ``UserWarning`` names the file and ``--z-positive down`` (or ``up`` to silence it,
      e.g. for a lake bed above sea level).
    """
    n = len(values)
    if n:
        positive = float(np.count_nonzero(values > 0)) / n
        negative = float(np.count_nonzero(values < 0)) / n
        median = float(np.median(values))
        if down and negative > 0.5:
            how = "--z-positive down" if explicit else "its column name (depth)"
            raise PointCloudError(
                f"{where}: the vertical values are read as depths (positive down, from {how}) but "
                f"{100 * negative:.0f}% of them are negative (median {median:.3f} m): they are elevations "
                "(positive up) already; pass --z-positive up (config: z_positive: up) to read them as z")
        if ambiguous and not explicit and positive > 0.5 and float(values.max()) <= MAX_DEPTH_M:
            import warnings

            warnings.warn(
                f"{where}: {100 * positive:.0f}% of the vertical values are positive (median {median:.3f} m) and "
                "nothing in the file says which way z points; if they are depths (positive down), pass "
                "--z-positive down (config: z_positive: down), else objects become pits; pass --z-positive up "
                "if they are elevations", UserWarning, stacklevel=2)
    if down:
        np.negative(values, out=values)
    return values
