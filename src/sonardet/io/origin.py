"""Local-origin shift for georeferenced point clouds.

Survey coordinates are large (UTM eastings ~5e5 m, northings ~4e6 m). float64 holds them to ~1e-9 m,
float32 only to 0.03-0.5 m (its spacing at 4e6 is 0.25-0.5 m). Every float32 or GPU stage (SASA, Open3D
tensor code, torch) must therefore work on *local* coordinates: ``local = xyz - origin`` computed in
float64, with a float64 ``origin`` kept alongside so results can be shifted back with
``xyz = local + origin``.

Where to use what
-----------------
* Readers (``sonardet.io.points.read_points``) return float64 coordinates in the file's frame
  (the CRS's, e.g. EPSG:32610 metres). Geometry on them stays float64.
* Before casting to float32 (``.astype(np.float32)``, ``torch.from_numpy(...).float()``, building
  float32 tensors, writing float32 buffers), get coordinates through :meth:`LocalFrame.to_local`
  (or ``PointCloud.local(np.float32)``), or cast through :func:`as_float32`. Code that receives
  coordinates from a caller and is about to cast them must call :func:`assert_local` first: it
  raises :class:`GlobalCoordinatesError` for coordinates beyond ``LOCAL_LIMIT_M`` (1e5 m).
* Outputs (box centres, poses, points) computed in the local frame are shifted back with
  :meth:`LocalFrame.to_global` (float64) before they are written next to the survey's CRS.

Choice of origin (:func:`choose_origin`): the bounding-box minimum of x and y, floored to a whole
metre (``round_m``), and z = 0. A round origin is easy to read in reports and files; local x, y are
then non-negative and no larger than the cloud's extent, so a cloud of extent E keeps float32
spacing below E * 6e-8 (0.06 mm at 1 km). z is not shifted so local z keeps the file's vertical
datum (elevation or depth, metres): survey z values are small (|z| < 1e4 m) and float32 holds them
to < 1 mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

__all__ = [
    "LOCAL_LIMIT_M",
    "GlobalCoordinatesError",
    "LocalFrame",
    "as_float32",
    "assert_local",
    "choose_origin",
    "to_global",
    "to_local",
]

#: Largest absolute coordinate (metres) allowed into float32 code. float32 spacing at 1e5 is
#: 7.8 mm; UTM coordinates (5e5 east, 4e6 north) are far above it, local ones far below.
LOCAL_LIMIT_M: float = 1.0e5


class GlobalCoordinatesError(ValueError):
    """Raised when global (e.g. UTM) coordinates reach code that needs local ones (float32 work)."""


def _as_xyz(xyz: ArrayLike, what: str = "xyz") -> np.ndarray:
    """Return ``xyz`` as an (N, 3) array without changing its dtype; raise on a wrong shape."""
    arr = np.asarray(xyz)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what}: expected an (N, 3) array of x, y, z in metres, got shape {arr.shape}")
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{what}: expected numeric coordinates, got dtype {arr.dtype}")
    return arr


def finite_xyz(xyz: ArrayLike, what: str = "xyz") -> np.ndarray:
    """``xyz`` as an (N, 3) float64 array (no copy when it already is one); raise ValueError on a
    wrong shape or dtype and, naming the first row and the count, on NaN/Inf coordinates."""
    arr = np.asarray(xyz)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what} must be an (N,3) array of x, y, z in metres, got shape {arr.shape}")
    arr = _as_xyz(arr, what).astype(np.float64, copy=False)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        row = int(np.argmax(bad))
        raise ValueError(f"{what} row {row} (0-based) holds NaN/Inf coordinates {arr[row].tolist()} "
                         f"({int(bad.sum())} row(s) affected); drop those points first")
    return arr


def _as_origin(origin: ArrayLike) -> np.ndarray:
    """Return ``origin`` as a finite float64 (3,) array; raise with the fix otherwise."""
    org = np.asarray(origin)
    if org.shape != (3,):
        raise ValueError(f"origin: expected 3 values (x, y, z in metres), got shape {org.shape}")
    if org.dtype.kind not in "fiu":
        raise ValueError(f"origin: expected numbers, got dtype {org.dtype}")
    org = org.astype(np.float64)
    if not np.all(np.isfinite(org)):
        raise ValueError(f"origin: must be finite, got {org.tolist()}")
    return org


def _max_abs(arr: np.ndarray) -> float:
    """Largest absolute finite value of ``arr`` (0.0 for an empty array)."""
    if arr.size == 0:
        return 0.0
    finite = np.isfinite(arr) if arr.dtype.kind == "f" else None
    if finite is not None and not finite.all():
        arr = arr[finite]
        if arr.size == 0:
            return 0.0
    return float(np.max(np.abs(arr)))


def choose_origin(xyz: ArrayLike, *, round_m: float = 1.0) -> np.ndarray:
    """Choose a local origin (float64, shape (3,), metres, in the frame of ``xyz``).

    x and y are the minimum of the points' x and y floored to a multiple of ``round_m`` (default a
    whole metre); z is 0 so that local z keeps the file's vertical datum. The result is
    deterministic for a given set of points. Raises ``ValueError`` for an empty array, a wrong
    shape, non-finite coordinates or a non-positive ``round_m``.
    """
    arr = _as_xyz(xyz)
    if arr.shape[0] == 0:
        raise ValueError("choose_origin: no points; a local origin needs at least one point")
    if not (np.isfinite(round_m) and round_m > 0):
        raise ValueError(f"choose_origin: round_m must be a positive number of metres, got {round_m!r}")
    mins = arr[:, :2].min(axis=0).astype(np.float64)
    if not np.all(np.isfinite(mins)) or not np.all(np.isfinite(arr[:, :2].max(axis=0))):
        raise ValueError("choose_origin: coordinates hold NaN or Inf; remove those points first")
    xy = np.floor(mins / round_m) * round_m
    return np.array([xy[0], xy[1], 0.0], dtype=np.float64)


def assert_local(xyz: ArrayLike, *, limit_m: float = LOCAL_LIMIT_M, what: str = "coordinates") -> None:
    """Raise :class:`GlobalCoordinatesError` if any |x|, |y| or |z| exceeds ``limit_m`` metres.

    Call it in any function that casts caller-supplied coordinates to float32 (or hands them to
    float32/GPU code): it turns the silent 0.25-0.5 m rounding of raw UTM coordinates into an error
    that says how to fix it. Non-finite values are ignored here (readers reject them).
    """
    arr = np.asarray(xyz)
    if arr.dtype.kind not in "fiu":
        raise ValueError(f"{what}: expected numeric coordinates, got dtype {arr.dtype}")
    peak = _max_abs(arr)
    if peak > limit_m:
        raise GlobalCoordinatesError(
            f"{what}: |coordinate| up to {peak:.3f} m exceeds the local-frame limit of {limit_m:g} m; "
            "these look like global (e.g. UTM) coordinates, which float32 resolves only to ~0.25-0.5 m. "
            "Shift them first: frame = LocalFrame.from_points(xyz); local = frame.to_local(xyz, "
            "dtype=np.float32) (or PointCloud.local(np.float32)), and frame.to_global(...) for results."
        )


def as_float32(xyz: ArrayLike, *, limit_m: float = LOCAL_LIMIT_M) -> np.ndarray:
    """Cast local coordinates (metres) to float32 after :func:`assert_local`; refuse global ones."""
    arr = np.asarray(xyz)
    assert_local(arr, limit_m=limit_m, what="as_float32")
    return arr.astype(np.float32)


def to_local(
    xyz: ArrayLike, origin: ArrayLike, *, dtype: DTypeLike = np.float64, limit_m: float = LOCAL_LIMIT_M
) -> np.ndarray:
    """Shift (N, 3) coordinates into the local frame: ``xyz - origin``, computed in float64.

    ``xyz`` and ``origin`` are metres in the same frame (e.g. UTM). The result is cast to
    ``dtype`` (float64 by default) only after the shift. When ``dtype`` is narrower than float64 the
    result is checked with :func:`assert_local` (an origin far from the points raises). Raises
    :class:`GlobalCoordinatesError` when ``xyz`` arrives already in float32 (or float16) with global
    magnitude: the precision is gone before the shift could save it.
    """
    arr = _as_xyz(xyz)
    org = _as_origin(origin)
    out_dtype = np.dtype(dtype)
    if out_dtype.kind != "f":
        raise ValueError(f"to_local: dtype must be a floating type, got {out_dtype}")
    if arr.dtype.kind == "f" and arr.dtype.itemsize < 8 and _max_abs(arr) > limit_m:
        raise GlobalCoordinatesError(
            f"to_local: input is already {arr.dtype} with |coordinate| > {limit_m:g} m, so it has lost "
            "0.03-0.5 m of precision; read and keep global coordinates in float64 "
            "(sonardet.io.points.read_points does)"
        )
    local = arr.astype(np.float64, copy=False) - org
    if out_dtype.itemsize < 8:
        assert_local(local, limit_m=limit_m, what="to_local result")
        return local.astype(out_dtype)
    return local.astype(out_dtype, copy=False)


def to_global(local: ArrayLike, origin: ArrayLike) -> np.ndarray:
    """Shift local (N, 3) coordinates (any float dtype, metres) back: ``local + origin`` in float64."""
    arr = _as_xyz(local, what="local")
    org = _as_origin(origin)
    return arr.astype(np.float64) + org


@dataclass(frozen=True)
class LocalFrame:
    """A local frame: float64 ``origin`` (3,) metres in the CRS ``crs`` (None if unknown).

    ``to_local``/``to_global`` shift (N, 3) arrays; ``to_dict``/``from_dict`` store the frame in
    JSON next to results computed in it.
    """

    origin: np.ndarray
    crs: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "origin", _as_origin(self.origin))
        self.origin.setflags(write=False)

    @classmethod
    def from_points(cls, xyz: ArrayLike, *, crs: str | None = None, round_m: float = 1.0) -> LocalFrame:
        """Frame with the origin :func:`choose_origin` picks for ``xyz`` (metres)."""
        return cls(choose_origin(xyz, round_m=round_m), crs)

    def to_local(self, xyz: ArrayLike, *, dtype: DTypeLike = np.float64) -> np.ndarray:
        """``xyz - origin`` in float64, then cast to ``dtype`` (see :func:`to_local`)."""
        return to_local(xyz, self.origin, dtype=dtype)

    def to_global(self, local: ArrayLike) -> np.ndarray:
        """``local + origin`` in float64 (see :func:`to_global`)."""
        return to_global(local, self.origin)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready ``{"origin": [x, y, z], "crs": crs}`` (floats round-trip exactly in JSON)."""
        return {"origin": [float(v) for v in self.origin], "crs": self.crs}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LocalFrame:
        """Inverse of :meth:`to_dict`."""
        if "origin" not in data:
            raise ValueError("LocalFrame.from_dict: missing 'origin' (list of 3 metres)")
        return cls(np.asarray(data["origin"], dtype=np.float64), data.get("crs"))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, LocalFrame):
            return NotImplemented
        return bool(np.array_equal(self.origin, other.origin)) and self.crs == other.crs

    def __hash__(self) -> int:
        return hash((tuple(self.origin.tolist()), self.crs))
