"""PLY point clouds (the ``vertex`` element), ascii or binary.

Reading uses trimesh's PLY parser (``trimesh.exchange.ply.load_ply``), which keeps each property's
stored dtype (its ``_ply_raw`` metadata); Open3D's reader is not used because it drops custom
properties. x, y, z are returned as float64: a file storing ``double`` keeps full precision, a file
storing ``float`` is widened exactly (the precision it has is what the file held). A ``float``
file with coordinates beyond 1e5 m is refused: at UTM magnitude float32 has already lost 0.03-0.5 m
(re-export it with ``double`` properties, or shifted to a local frame). Every other scalar vertex
property becomes an attribute with its stored dtype; list properties and other elements (faces)
are ignored. Header comments ``comment crs <CRS>`` and ``comment sonardet_origin <x> <y> <z>`` give
the CRS and local origin.

Writing is a small numpy writer (trimesh's exporter stores vertices as float32, which would lose
UTM precision): ``binary_little_endian``, ``property double x/y/z`` followed by one scalar property
per attribute in its dtype (bool -> uchar; int64/uint64 -> int/uint when the values fit, else an
error, since PLY has no 64-bit integers), plus the two comments above.

There is no streaming reader: :func:`iter_chunks` reads the file whole and yields slices of it.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from sonardet.io.atomic import atomic_path
from sonardet.io.points.core import DEFAULT_CHUNK_POINTS, PointCloud, PointCloudError, iter_slices, merge_crs

__all__ = ["NAME", "SUFFIXES", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS", "read", "write", "iter_chunks"]

#: Format key (``sonardet.io.points.point_format``).
NAME = "ply"
#: File suffixes of this format.
SUFFIXES: tuple[str, ...] = (".ply",)
#: Whether :func:`iter_chunks` reads the file chunk by chunk (False: whole, then sliced).
STREAMED = False
#: Keywords of ``read_points`` / ``write_points`` this format takes.
READ_OPTIONS: tuple[str, ...] = ()
WRITE_OPTIONS: tuple[str, ...] = ()

_MAX_HEADER_BYTES = 1 << 20
_PLY_TYPES = {
    np.dtype("f8"): "double",
    np.dtype("f4"): "float",
    np.dtype("i4"): "int",
    np.dtype("u4"): "uint",
    np.dtype("i2"): "short",
    np.dtype("u2"): "ushort",
    np.dtype("i1"): "char",
    np.dtype("u1"): "uchar",
}


def _parse_header(path: Path) -> tuple[str | None, np.ndarray | None, list[str] | None]:
    """(crs, origin, vertex property names) from the header; None where absent."""
    where = str(path)
    crs: str | None = None
    origin: np.ndarray | None = None
    element: str | None = None
    vertex_props: list[str] | None = None
    with open(path, "rb") as fh:
        read = 0
        while True:
            raw = fh.readline(_MAX_HEADER_BYTES)
            read += len(raw)
            if not raw or read > _MAX_HEADER_BYTES:
                raise PointCloudError(f"{where}: no 'end_header' line in the first 1 MiB; not a PLY file")
            line = raw.decode("ascii", errors="replace").strip()
            if line == "end_header":
                return crs, origin, vertex_props
            words = line.split()
            if words[:1] == ["element"] and len(words) >= 2:
                element = words[1]
                if element == "vertex":
                    vertex_props = []
            elif words[:1] == ["property"] and element == "vertex" and vertex_props is not None and len(words) >= 3:
                vertex_props.append(words[-1])
            elif line.startswith("comment crs "):
                crs = line[len("comment crs ") :].strip() or None
            elif line.startswith("comment sonardet_origin "):
                parts = line.split()[2:]
                try:
                    origin = np.array([float(v) for v in parts], dtype=np.float64)
                except ValueError as exc:
                    raise PointCloudError(f"{where}: bad 'comment sonardet_origin' line {line!r}") from exc
                if origin.shape != (3,):
                    raise PointCloudError(f"{where}: 'comment sonardet_origin' needs 3 numbers, got {line!r}")


def read(path: str | Path, *, crs: str | None = None) -> PointCloud:
    """Read the vertices of a ``.ply`` file: x, y, z float64 metres (the file's frame), scalar properties
    as attributes, CRS and origin from the header comments; ``crs`` as in ``read_points``."""
    from trimesh.exchange.ply import load_ply

    p = Path(path)
    where = str(p)
    with open(p, "rb") as fh:
        magic = fh.read(4)
    if magic[:3] != b"ply":
        raise PointCloudError(f"{where}: not a PLY file (it does not start with 'ply')")
    file_crs, origin, header_props = _parse_header(p)
    if header_props is None:
        raise PointCloudError(f"{where}: no points (the file has no 'vertex' element)")
    missing = [a for a in "xyz" if a not in header_props]
    if missing:
        raise PointCloudError(f"{where}: vertex element lacks properties {missing}; it has {header_props}")
    try:
        with open(p, "rb") as fh:
            loaded = load_ply(fh)
    except Exception as exc:  # trimesh raises ValueError/KeyError/IndexError on malformed files
        raise PointCloudError(f"{where}: cannot parse the PLY file ({type(exc).__name__}: {exc})") from exc
    elements = loaded.get("metadata", {}).get("_ply_raw", {})
    if "vertex" not in elements:
        raise PointCloudError(f"{where}: no points (the file has no 'vertex' element)")
    vertex = elements["vertex"]
    n = int(vertex["length"])
    if n == 0:
        raise PointCloudError(f"{where}: no points (the vertex element is empty)")
    props = list(vertex["properties"])
    missing = [a for a in "xyz" if a not in props]
    if missing:
        raise PointCloudError(f"{where}: vertex element lacks properties {missing}; it has {props}")
    data = vertex["data"]

    def column(name: str) -> np.ndarray | None:
        arr = np.asarray(data[name])
        if arr.ndim == 2 and arr.shape[1] == 1:
            arr = arr[:, 0]
        return arr if arr.ndim == 1 and arr.shape[0] == n and arr.dtype.kind in "biuf" else None

    cols = [column(a) for a in "xyz"]
    if any(c is None for c in cols):
        raise PointCloudError(f"{where}: vertex properties x, y, z must be numeric scalars")
    xyz = np.column_stack(cols)  # keeps the stored dtype; PointCloud widens or refuses float32
    attrs: dict[str, np.ndarray] = {}
    for name in props:
        if name in ("x", "y", "z"):
            continue
        arr = column(name)
        if arr is not None:
            attrs[name] = np.array(arr)
    return PointCloud(xyz, attrs, crs=merge_crs(file_crs, crs, where), source=where, origin=origin)


def _ply_dtype(name: str, values: np.ndarray, where: str) -> tuple[np.ndarray, str]:
    """(values in a PLY-representable dtype, PLY type name); raise if that would lose values."""
    arr = values
    if arr.dtype.kind == "b":
        arr = arr.astype(np.uint8)
    elif arr.dtype.kind in "iu" and arr.dtype.itemsize == 8:
        target = np.dtype("i4") if arr.dtype.kind == "i" else np.dtype("u4")
        info = np.iinfo(target)
        if len(arr) and (arr.min() < info.min or arr.max() > info.max):
            raise PointCloudError(
                f"{where}: attribute {name!r} has {arr.dtype} values beyond {target} and PLY has no 64-bit "
                "integers; store it as float64 or write .npz"
            )
        arr = arr.astype(target)
    elif arr.dtype == np.float16:
        arr = arr.astype(np.float32)
    dt = arr.dtype.newbyteorder("<") if arr.dtype.itemsize > 1 else arr.dtype
    key = np.dtype(dt.str.replace("<", "").replace(">", "").replace("|", ""))
    if key not in _PLY_TYPES:
        raise PointCloudError(f"{where}: attribute {name!r} has dtype {values.dtype}, which PLY cannot store")
    return arr, _PLY_TYPES[key]


def write(path: str | Path, cloud: PointCloud) -> None:
    """Write ``cloud`` as binary little-endian PLY with ``double`` x, y, z (metres), atomically."""
    from sonardet import __version__

    p = Path(path)
    where = str(p)
    columns: list[tuple[str, np.ndarray, str]] = [(a, cloud.xyz[:, i], "double") for i, a in enumerate("xyz")]
    for name, values in cloud.attributes.items():
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.\-]*", name):
            raise PointCloudError(f"{where}: attribute name {name!r} is not a valid PLY property name; rename it")
        arr, ptype = _ply_dtype(name, values, where)
        columns.append((name, arr, ptype))
    dtype = np.dtype([(name, arr.dtype.newbyteorder("<")) for name, arr, _ in columns])
    table = np.empty(len(cloud), dtype=dtype)
    for name, arr, _ in columns:
        table[name] = arr
    lines = ["ply", "format binary_little_endian 1.0", f"comment generated by sonardet {__version__}"]
    if cloud.crs is not None:
        lines.append("comment crs " + " ".join(cloud.crs.split()))
    if cloud.origin is not None:
        lines.append("comment sonardet_origin " + " ".join(repr(float(v)) for v in cloud.origin))
    lines.append(f"element vertex {len(cloud)}")
    lines += [f"property {ptype} {name}" for name, _, ptype in columns]
    lines.append("end_header")
    with atomic_path(p) as tmp, open(tmp, "wb") as fh:
        fh.write(("\n".join(lines) + "\n").encode("utf-8"))
        fh.write(table.tobytes())


def iter_chunks(
    path: str | Path, *, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS
) -> Iterator[PointCloud]:
    """The file's x, y, z (float64 metres, the file's frame) in chunks of at most ``chunk_points`` points,
    in file order, each a :class:`PointCloud` without attributes carrying the file's CRS and origin. The
    file is read whole (24 bytes per point and more for its properties) and sliced; errors are those of
    :func:`read`."""
    yield from iter_slices(read(path, crs=crs), chunk_points)
