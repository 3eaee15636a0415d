"""NPZ point clouds (the scene format of DESIGN.md section 3).

Format: ``xyz`` (N, 3) float64; any number of per-point 1-D arrays of length N (``ping``, ``beam``,
``line``, ``label``, ...), which become ``PointCloud.attributes``; optional ``origin`` (3,) float64,
the local frame's origin in the frame of ``xyz`` (so ``local = xyz - origin``; ``xyz`` itself is
stored as is, never pre-shifted); optional ``crs``, a 0-d string array. Any other entry is an error
(nothing is silently dropped).

Writing keeps everything bit-exactly, atomically and with deterministic bytes (fixed zip time stamps).
There is no streaming reader: :func:`iter_chunks` reads the file whole and yields slices of it.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sonardet.io.artifacts import FileReadError, read_npz
from sonardet.io.atomic import atomic_path
from sonardet.io.points.core import DEFAULT_CHUNK_POINTS, PointCloud, PointCloudError, iter_slices, merge_crs

__all__ = ["NAME", "SUFFIXES", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS", "read", "write", "iter_chunks"]

#: Format key (``sonardet.io.points.point_format``).
NAME = "npz"
#: File suffixes of this format.
SUFFIXES: tuple[str, ...] = (".npz",)
#: Whether :func:`iter_chunks` reads the file chunk by chunk (False: whole, then sliced).
STREAMED = False
#: Keywords of ``read_points`` / ``write_points`` this format takes.
READ_OPTIONS: tuple[str, ...] = ()
WRITE_OPTIONS: tuple[str, ...] = ("compress",)

_ZIP_DATE = (1980, 1, 1, 0, 0, 0)


def read(path: str | os.PathLike, *, crs: str | None = None) -> PointCloud:
    """Read a scene ``.npz`` (see the module docstring): ``xyz`` float64 metres as stored (the file's
    frame), per-point attributes, origin (m, same frame) and CRS; ``crs`` as in ``read_points``."""
    p = Path(path)
    where = str(p)
    hint = "rewrite it with write_points (a tile or scene the workflow wrote: delete it and rerun the step that writes it)"
    try:
        data = read_npz(p, "point-cloud .npz file", hint=hint)
    except FileReadError as exc:  # truncated or damaged archive or entry, pickled objects: named in the message
        raise PointCloudError(str(exc)) from exc
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
    return PointCloud(xyz, attrs, crs=merge_crs(file_crs, crs, where), source=where, origin=origin)


def write(path: str | os.PathLike, cloud: PointCloud, *, compress: bool = True) -> None:
    """Write ``cloud`` as a scene ``.npz``: xyz float64 metres as held, attributes, origin and CRS
    (``np.load``-compatible, deterministic bytes, atomic). ``compress``: deflate the arrays."""
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


def iter_chunks(
    path: str | os.PathLike, *, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS
) -> Iterator[PointCloud]:
    """The file's x, y, z (float64 metres, the file's frame) in chunks of at most ``chunk_points`` points,
    in file order, each a :class:`PointCloud` without attributes carrying the file's CRS and origin. The
    file is read whole (24 bytes per point) and sliced; errors are those of :func:`read`."""
    yield from iter_slices(read(path, crs=crs), chunk_points)
