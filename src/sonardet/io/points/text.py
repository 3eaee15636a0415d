"""Plain-text point clouds: ``.xyz``, ``.txt``, ``.pts``, ``.csv`` and their ``.gz`` variants.

Reading
-------
* Delimiter: comma if the first content line holds a comma, else semicolon if it holds one, else
  any run of whitespace (spaces, tabs).
* Blank lines and lines starting with ``#`` are skipped; text after ``#`` on a line is a comment.
* Header: the first content line is a header when any of its fields is not a number. A leading
  ``//`` (CloudCompare) is stripped. ``.pts`` files may start with a point-count line (Leica PTS),
  which is checked against the points read.
* Column names map to coordinates case-insensitively after removing units in brackets
  (``"Easting (m)"``), quotes and a trailing ``_m``:

  - x: ``x``, ``easting``, ``east``, ``e``; or longitude ``lon``, ``long``, ``longitude`` (degrees)
  - y: ``y``, ``northing``, ``north``, ``n``; or latitude ``lat``, ``latitude`` (degrees)
  - z: ``elevation``, ``elev``, ``height``, ``altitude``, ``alt`` (positive up by name), ``z``
    (positive up unless ``z_positive="down"``), or ``depth`` (positive down by name: ``z = -depth``)
    when no elevation column exists.
  - ``z_positive`` (``--z-positive up|down``) states the direction of the vertical column and wins
    over its name. The checks of ``core.apply_z_positive`` apply: depths that are mostly negative are
    refused (they are elevations), and a headerless file or a plain ``z`` column whose values are
    mostly positive gets a warning naming ``--z-positive down``.
  - Longitude/latitude columns (without x/y) give a cloud in the CRS EPSG:4326 (or the geographic
    ``crs=`` given; a projected one is refused): x = longitude, y = latitude in degrees. Projecting to
    metres is the caller's step (``sonardet.io.crs.utm_projection``).

  Every other column that holds numbers becomes an attribute under its header name (ints stay
  int64, floats float64, ``True``/``False`` bool); a column whose first value is not a number
  (e.g. a date string) is dropped with a warning.
* Without a header the first three columns are x, y, z and extra columns become attributes
  ``col3``, ``col4``, ... (0-based column index). ``columns=[...]`` names the columns instead.
* Speed: one pass of ``pandas.read_csv`` (C engine, exact float64 parsing). Only when that pass
  reports a problem does a slow line-by-line pass run to name the offending line.

Chunked reading (:func:`iter_chunks`) streams the file through the same parser, ``chunk_points`` rows
at a time, and yields x, y, z only (same layout detection and values as :func:`read`; attribute
columns are not kept). A problem in a chunk is
reported by :func:`read` on the whole file, whose message names the line. ``columns=`` and ``z_positive=``
apply as in :func:`read`; the vertical checks run on the first chunk.

Writing
-------
Columns x, y, z, then attributes in dict order. ``.csv`` uses commas, the others a single space.
A header line is written for ``.csv`` and whenever the cloud has attributes (so their names
survive), never for ``.pts`` (which gets its count line). Floats are written as the shortest
string that reads back to the identical float64 (or with ``decimals`` fixed decimals); float32
attributes get float32's shortest string (read back as float64, equal after a cast to float32);
booleans are written as 0/1 (read back as int64). ``.gz``
output has a zero time stamp and no file name, so equal clouds give equal bytes. CRS and origin
are not stored in text files.
"""

from __future__ import annotations

import gzip
import io
import re
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sonardet.io.atomic import atomic_path
from sonardet.io.crs import LONLAT_CRS, is_geographic
from sonardet.io.points.core import (
    DEFAULT_CHUNK_POINTS,
    PLAUSIBLE_XY_M,
    PLAUSIBLE_Z_M,
    PointCloud,
    PointCloudError,
    apply_z_positive,
    check_finite,
    check_plausible,
    check_z_positive,
    merge_crs,
)

__all__ = [
    "NAME", "SUFFIXES", "BASE_SUFFIXES", "STREAMED", "READ_OPTIONS", "WRITE_OPTIONS", "AXIS_ALIASES",
    "DEPTH_NAMES", "LONLAT_ALIASES", "read", "write", "iter_chunks",
]

#: Format key (``sonardet.io.points.point_format``).
NAME = "text"
#: Plain-text suffixes; each may also end in ``.gz``.
BASE_SUFFIXES: tuple[str, ...] = (".xyz", ".txt", ".pts", ".csv")
#: File suffixes of this format.
SUFFIXES: tuple[str, ...] = (*BASE_SUFFIXES, *(s + ".gz" for s in BASE_SUFFIXES))
#: Whether :func:`iter_chunks` reads the file chunk by chunk.
STREAMED = True
#: Keywords of ``read_points`` / ``write_points`` this format takes.
READ_OPTIONS: tuple[str, ...] = ("columns", "z_positive")
WRITE_OPTIONS: tuple[str, ...] = ("header", "decimals")

AXIS_ALIASES: dict[str, tuple[str, ...]] = {
    "x": ("x", "easting", "east", "e"),
    "y": ("y", "northing", "north", "n"),
    "z": ("z", "elevation", "elev", "height", "altitude", "alt"),
}
#: Names of a positive-down vertical column.
DEPTH_NAMES: tuple[str, ...] = ("depth",)
#: Names of longitude (x) and latitude (y) columns, in degrees.
LONLAT_ALIASES: dict[str, tuple[str, ...]] = {"x": ("lon", "long", "longitude"), "y": ("lat", "latitude")}

_ENCODING = "utf-8-sig"
_UNITS = re.compile(r"[\(\[].*?[\)\]]")


def _base_suffix(path: Path) -> tuple[str, bool]:
    """('.xyz'|'.txt'|'.pts'|'.csv', gzipped?) from the file name."""
    name = path.name.lower()
    gz = name.endswith(".gz")
    if gz:
        name = name[:-3]
    return Path(name).suffix, gz


def _open_text(path: Path, gz: bool) -> io.TextIOBase:
    """Open a (possibly gzipped) text file for line iteration."""
    if gz:
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding=_ENCODING, errors="replace")
    return open(path, encoding=_ENCODING, errors="replace")


def _split(line: str, delim: str | None) -> list[str]:
    """Fields of one line (comment removed); quotes and surrounding spaces stripped for CSV."""
    line = line.split("#", 1)[0]
    if delim is None:
        return line.split()
    return [t.strip().strip('"').strip("'").strip() for t in line.rstrip("\r\n").split(delim)]


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _normalize(name: str) -> str:
    """Column name as matched against the aliases: 'Easting (m)' -> 'easting', 'Z_m' -> 'z'."""
    n = _UNITS.sub("", name.strip().strip('"').strip("'")).strip().lower()
    n = re.sub(r"[\s\-]+", "_", n)
    if n.endswith("_m") and len(n) > 2:
        n = n[:-2]
    return n


@dataclass
class _Layout:
    """What the first lines of a text file say."""

    skip: int  # physical lines before the first data line
    delim: str | None  # None = whitespace
    header: list[str] | None
    count: int | None  # PTS point-count line
    first_tokens: list[str]
    first_line: int  # 1-based line number of the first data line


def _peek(path: Path, gz: bool, is_pts: bool) -> _Layout:
    """Find delimiter, header, PTS count line and the first data line."""
    where = str(path)
    header: list[str] | None = None
    count: int | None = None
    delim: str | None = None
    decided = False
    try:
        with _open_text(path, gz) as fh:
            for lineno, raw in enumerate(fh, start=1):
                content = raw.split("#", 1)[0].strip()
                if not content:
                    continue
                if not decided:
                    probe = content[2:] if content.startswith("//") else content
                    delim = "," if "," in probe else (";" if ";" in probe else None)
                    decided = True
                    tokens = _split(probe, delim)
                    if is_pts and len(tokens) == 1 and tokens[0].isdigit():
                        count = int(tokens[0])
                        decided = False  # the next line decides delimiter and header
                        continue
                    if not all(_is_number(t) for t in tokens):
                        header = tokens
                        continue
                    return _Layout(lineno - 1, delim, header, count, tokens, lineno)
                tokens = _split(content, delim)
                return _Layout(lineno - 1, delim, header, count, tokens, lineno)
    except (OSError, EOFError) as exc:
        raise PointCloudError(f"{where}: cannot read the file ({exc}); is it a complete {'gzip ' if gz else ''}text file?") from exc
    what = "holds only a header line" if header is not None else "is empty or holds only comments"
    raise PointCloudError(f"{where}: no points (the file {what})")


def _data_lines(path: Path, gz: bool, layout: _Layout) -> Iterator[tuple[int, list[str]]]:
    """(1-based line number, fields) of every data line, as the fast reader sees them."""
    with _open_text(path, gz) as fh:
        for lineno, raw in enumerate(fh, start=1):
            if lineno <= layout.skip:
                continue
            if not raw.split("#", 1)[0].strip():
                continue
            yield lineno, _split(raw, layout.delim)


def _diagnose(
    path: Path, gz: bool, layout: _Layout, expected: int, check: dict[int, str], stop_row: int | None = None
) -> int | None:
    """Slow pass: raise naming the first line with a wrong column count or an unparsable number.

    ``check`` maps column index -> name for the columns that must be numbers. With ``stop_row``
    it returns the line number of that 0-based data row instead (None if there are fewer rows).
    """
    where = str(path)
    for row, (lineno, tokens) in enumerate(_data_lines(path, gz, layout)):
        if len(tokens) != expected:
            raise PointCloudError(
                f"{where} line {lineno}: expected {expected} columns, found {len(tokens)}; "
                "fix or remove that line (every line needs the same columns)"
            )
        for col, name in check.items():
            if not _is_number(tokens[col]):
                raise PointCloudError(
                    f"{where} line {lineno}, column {col + 1} ({name}): cannot parse {tokens[col]!r} as a "
                    "number; fix or remove that line"
                )
        if stop_row is not None and row == stop_row:
            return lineno
    return None


@dataclass(frozen=True)
class _Axes:
    """How a file's columns map to coordinates: column indices of x, y, z; z from a positive-down column;
    z's direction unknown from the file (a plain ``z`` or a headerless file); x/y are longitude/latitude."""

    xyz: tuple[int, int, int]
    down: bool
    ambiguous: bool
    lonlat: bool


def _find(norm: list[str], names: list[str], aliases: tuple[str, ...], axis: str, where: str) -> int | None:
    """Index of the one column whose normalised name is among `aliases` (None if none); two raise."""
    hits = [i for i, n in enumerate(norm) if n in aliases]
    if len(hits) > 1:
        raise PointCloudError(
            f"{where}: header columns {[names[i] for i in hits]} all name {axis}; keep one, or pass "
            "columns=[...] (--columns) to name the columns explicitly"
        )
    return hits[0] if hits else None


def _resolve(names: list[str], where: str, z_positive: str | None) -> _Axes:
    """The coordinate columns of a file with column `names` and the vertical direction (see the module
    doc); raises naming the accepted names when a coordinate is missing."""
    norm = [_normalize(n) for n in names]
    found = {axis: _find(norm, names, aliases, axis, where) for axis, aliases in AXIS_ALIASES.items()}
    lonlat = False
    if found["x"] is None and found["y"] is None:
        ll = {axis: _find(norm, names, aliases, axis, where) for axis, aliases in LONLAT_ALIASES.items()}
        if ll["x"] is not None and ll["y"] is not None:
            found.update(ll)
            lonlat = True
    down = False
    if found["z"] is None:
        depth = [i for i, n in enumerate(norm) if n in DEPTH_NAMES]
        if depth:
            found["z"], down = depth[0], True
    ambiguous = found["z"] is not None and not down and norm[found["z"]] == "z"
    if z_positive is not None:
        down = z_positive == "down"
    missing = [a for a in "xyz" if found[a] is None]
    if missing:
        raise PointCloudError(
            f"{where}: cannot find column(s) {missing} among {names}; accepted names: "
            f"{ {a: list(v) for a, v in AXIS_ALIASES.items()} }, depth (positive down), lon/lat "
            f"{ {a: list(v) for a, v in LONLAT_ALIASES.items()} } (case-insensitive), or pass columns=[...] "
            "(--columns x,y,z,...) naming every column"
        )
    return _Axes((found["x"], found["y"], found["z"]), down, ambiguous, lonlat)


def _cloud_crs(axes: _Axes, crs: str | None, where: str) -> str | None:
    """The CRS of a text cloud: ``crs`` as given; for longitude/latitude columns EPSG:4326 when none is
    given, and a projected ``crs`` is refused."""
    if not axes.lonlat:
        return merge_crs(None, crs, where)
    if crs is None:
        return LONLAT_CRS
    if not is_geographic(crs):
        raise PointCloudError(f"{where}: the columns hold longitude/latitude but the CRS given (--crs) is {crs}, "
                              "not geographic; leave --crs out (EPSG:4326 is assumed) or give a geographic CRS")
    return merge_crs(None, crs, where)


@dataclass
class _Columns:
    """A text file's layout and how its columns map to x, y, z (column indices ``xyz``)."""

    path: Path
    gz: bool
    layout: _Layout
    names: list[str]
    axes: _Axes

    @property
    def xyz(self) -> tuple[int, int, int]:
        """Column indices of x, y, z."""
        return self.axes.xyz

    @property
    def where(self) -> str:
        """The file, as messages name it."""
        return str(self.path)

    def xyz_check(self) -> dict[int, str]:
        """Column index -> name of the coordinate columns (which must hold numbers)."""
        return {i: self.names[i] for i in self.xyz}

    def diagnose(self, check: dict[int, str] | None = None, stop_row: int | None = None) -> int | None:
        """`_diagnose` on this file (default check: the coordinate columns)."""
        check = self.xyz_check() if check is None else check
        return _diagnose(self.path, self.gz, self.layout, len(self.names), check, stop_row)


def _column_names(layout: _Layout, columns: Sequence[str] | None, where: str) -> list[str]:
    """Names of the columns in file order: ``columns=``, else the header, else x, y, z, col3, ..."""
    ncols_first = len(layout.first_tokens)
    if columns is not None:
        names = [str(c).strip() for c in columns]
    elif layout.header is not None:
        names = [h.strip() for h in layout.header]
    else:
        names = ["x", "y", "z"] + [f"col{i}" for i in range(3, ncols_first)]
    if columns is not None and layout.header is not None and len(names) != len(layout.header):
        raise PointCloudError(
            f"{where}: columns= names {len(names)} columns but the header has {len(layout.header)}"
        )
    if len(names) < 3 and layout.header is None and columns is None:
        raise PointCloudError(
            f"{where} line {layout.first_line}: expected at least 3 columns (x y z), found {ncols_first}"
        )
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise PointCloudError(f"{where}: duplicate column names {dup}; rename them or pass columns=[...]")
    return names


def _csv_options(layout: _Layout, gz: bool) -> dict:
    """Keywords of ``pandas.read_csv`` for the data lines of a file with this layout (C engine)."""
    sep_kw: dict = {"sep": r"\s+"} if layout.delim is None else {"sep": layout.delim, "skipinitialspace": True}
    return dict(header=None, skiprows=layout.skip, comment="#", engine="c", compression="gzip" if gz else None,
                encoding=_ENCODING, encoding_errors="replace", skip_blank_lines=True, index_col=False, **sep_kw)


def _read_frame(cols: _Columns):
    """The data lines as a pandas DataFrame (one fast pass); raise naming the line on a bad file."""
    import pandas as pd

    where = cols.where
    try:
        df = pd.read_csv(cols.path, **_csv_options(cols.layout, cols.gz))
    except pd.errors.ParserError as exc:
        cols.diagnose()
        raise PointCloudError(f"{where}: cannot parse the file ({exc})") from exc
    except pd.errors.EmptyDataError as exc:
        raise PointCloudError(f"{where}: no points") from exc
    except (OSError, EOFError, UnicodeError) as exc:
        raise PointCloudError(f"{where}: cannot read the file ({exc})") from exc
    if df.shape[1] != len(cols.names):
        cols.diagnose()
        raise PointCloudError(f"{where}: expected {len(cols.names)} columns, the file has {df.shape[1]}")
    if df.shape[0] == 0:
        raise PointCloudError(f"{where}: no points")
    return df


def _attribute_columns(df, cols: _Columns) -> list[int]:
    """Indices of the attribute columns to keep. Coordinates must be numeric; attribute columns are kept
    when numeric, dropped with a warning when their first value is not a number, refused otherwise."""
    import pandas as pd

    names, first_tokens = cols.names, cols.layout.first_tokens
    bad_numeric: dict[int, str] = {}
    keep: list[int] = []
    for i in range(len(names)):
        col = df.iloc[:, i]
        numeric = pd.api.types.is_numeric_dtype(col) or pd.api.types.is_bool_dtype(col)
        if i in cols.xyz:
            if not numeric:
                bad_numeric[i] = names[i]
            continue
        if numeric:
            keep.append(i)
        elif _is_number(str(first_tokens[i]) if i < len(first_tokens) else ""):
            bad_numeric[i] = names[i]
        else:
            # stacklevel: this helper, read, read_points, the caller of read_points.
            warnings.warn(f"{cols.where}: column {names[i]!r} is not numeric and is not kept", stacklevel=4)
    if bad_numeric:
        cols.diagnose({**cols.xyz_check(), **bad_numeric})
        raise PointCloudError(f"{cols.where}: columns {list(bad_numeric.values())} hold values that are not numbers")
    return keep


def _coordinates(df, cols: _Columns, z_positive: str | None) -> np.ndarray:
    """x, y, z of the rows, float64 (N, 3) metres (z = -depth for a positive-down column, checked by
    `apply_z_positive`); NaN/Inf refused with the line named."""
    xyz = np.empty((df.shape[0], 3), dtype=np.float64)
    for k, i in enumerate(cols.xyz):
        xyz[:, k] = df.iloc[:, i].to_numpy(dtype=np.float64)
    apply_z_positive(xyz[:, 2], cols.axes.down, ambiguous=cols.axes.ambiguous, explicit=z_positive is not None,
                     where=cols.where)
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        row = int(np.argmin(finite))
        lineno = cols.diagnose(stop_row=row)
        lines = {row: lineno} if lineno is not None else None
        check_finite(xyz, cols.where, line_of_row=lines)  # raises
    bad = _implausible(xyz)
    if bad.any():
        row = int(np.argmax(bad))
        lineno = cols.diagnose(stop_row=row)
        check_plausible(xyz, cols.where, line_of_row={row: lineno} if lineno is not None else None)  # raises
    return xyz


def _implausible(xyz: np.ndarray) -> np.ndarray:
    """Rows of xyz (m) beyond any survey (`check_plausible`)."""
    return (np.abs(xyz[:, :2]) > PLAUSIBLE_XY_M).any(axis=1) | (np.abs(xyz[:, 2]) > PLAUSIBLE_Z_M)


def _check_count(layout: _Layout, n_points: int, where: str) -> None:
    """Refuse a PTS file whose count line disagrees with the points read."""
    if layout.count is not None and layout.count != n_points:
        raise PointCloudError(
            f"{where}: the PTS count line says {layout.count} points but {n_points} were read; "
            "fix the count line or the truncated file"
        )


def _open_layout(path, crs, columns, z_positive):
    """What :func:`read` and :func:`iter_chunks` learn of a text file before parsing it: (path, its name
    for messages, gzipped, layout, column names, resolved axes, the cloud's CRS); ``crs``, ``columns``
    and ``z_positive`` as in ``read_points``."""
    p = Path(path)
    where = str(p)
    check_z_positive(z_positive, where)
    suffix, gz = _base_suffix(p)
    layout = _peek(p, gz, suffix == ".pts")
    names = _column_names(layout, columns, where)
    axes = _resolve(names, where, z_positive)
    return p, where, gz, layout, names, axes, _cloud_crs(axes, crs, where)


def read(
    path: str | Path,
    *,
    crs: str | None = None,
    columns: Sequence[str] | None = None,
    z_positive: str | None = None,
) -> PointCloud:
    """Read a text point cloud (see the module docstring): xyz float64 as written in the file (the
    file's frame: metres, or degrees for longitude/latitude columns; z up), numeric extra columns as
    attributes; ``columns``, ``crs`` and ``z_positive`` as in ``read_points``."""
    p, where, gz, layout, names, axes, cloud_crs = _open_layout(path, crs, columns, z_positive)
    cols = _Columns(p, gz, layout, names, axes)
    df = _read_frame(cols)
    keep = _attribute_columns(df, cols)
    if df.isna().to_numpy().any():
        # Short lines are filled with NaN by the fast reader: find them (and bad tokens) first.
        cols.diagnose()
    xyz = _coordinates(df, cols, z_positive)
    _check_count(layout, xyz.shape[0], where)
    attrs = {names[i]: df.iloc[:, i].to_numpy() for i in keep}
    return PointCloud(xyz, attrs, crs=cloud_crs, source=where)


def write(path: str | Path, cloud: PointCloud, *, header: bool | None = None, decimals: int | None = None) -> None:
    """Write ``cloud`` as text (see the module docstring), atomically: x, y, z in metres as held (the
    cloud's frame), then the attributes; ``header`` and ``decimals`` as in ``write_points``."""
    import pandas as pd

    p = Path(path)
    where = str(p)
    suffix, gz = _base_suffix(p)
    delim = "," if suffix == ".csv" else " "
    if suffix == ".pts":
        if header:
            raise PointCloudError(f"{where}: PTS files have no header line; write .xyz or .csv to keep names")
        header = False
    elif header is None:
        header = suffix == ".csv" or bool(cloud.attributes)
    if header:
        for name in cloud.attributes:
            if delim in name or any(c.isspace() for c in name) or "#" in name:
                raise PointCloudError(
                    f"{where}: attribute name {name!r} contains the delimiter, whitespace or '#'; rename it"
                )
    if decimals is not None and (not isinstance(decimals, int) or decimals < 0):
        raise PointCloudError(f"{where}: decimals must be a non-negative int, got {decimals!r}")
    data = {"x": cloud.xyz[:, 0], "y": cloud.xyz[:, 1], "z": cloud.xyz[:, 2]}
    for name, values in cloud.attributes.items():
        data[name] = values.astype(np.uint8) if values.dtype.kind == "b" else values
    df = pd.DataFrame(data, copy=False)
    float_format = None if decimals is None else f"%.{decimals}f"
    with atomic_path(p) as tmp, open(tmp, "wb") as raw:
        stream = gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0) if gz else raw
        fh = io.TextIOWrapper(stream, encoding="utf-8", newline="")
        if suffix == ".pts":
            fh.write(f"{len(cloud)}\n")
        df.to_csv(fh, sep=delim, header=bool(header), index=False, float_format=float_format, lineterminator="\n")
        fh.flush()
        fh.detach()  # leave ``stream`` open: closing it here would close ``raw`` too
        if gz:
            stream.close()  # writes the gzip trailer; a GzipFile does not close its ``fileobj``


def _reader_error(path: Path, crs: str | None, what: str, **options):
    """Raise the whole-file reader's error for a problem found in a chunk (it names the line and the
    fix); if the whole-file reader accepts the file after all, raise a PointCloudError saying `what`."""
    read(path, crs=crs, **options)
    raise PointCloudError(f"{path}: {what}; the chunked reader cannot read it (read_points can: convert the "
                          "file to .npz)")


def _chunk_xyz(df, xyz_cols: tuple[int, int, int], path: Path, n_before: int, options: dict) -> np.ndarray:
    """x, y, z (float64 (n, 3), as in the file) of one parsed chunk; raise (`_reader_error`) for a
    non-number or NaN/Inf."""
    import pandas as pd

    cols = [df.iloc[:, i] for i in xyz_cols]
    if not all(pd.api.types.is_numeric_dtype(c) for c in cols):
        _reader_error(path, options["crs"], f"a coordinate after point {n_before} is not a number", **options["read"])
    xyz = np.empty((len(df), 3), dtype=np.float64)
    for k, c in enumerate(cols):
        xyz[:, k] = c.to_numpy(dtype=np.float64)
    if not np.isfinite(xyz).all():
        _reader_error(path, options["crs"], f"non-finite coordinates after point {n_before}", **options["read"])
    if _implausible(xyz).any():
        _reader_error(path, options["crs"], f"implausible coordinates after point {n_before}", **options["read"])
    return xyz


def iter_chunks(
    path: str | Path, *, crs: str | None = None, chunk_points: int = DEFAULT_CHUNK_POINTS,
    columns: Sequence[str] | None = None, z_positive: str | None = None,
) -> Iterator[PointCloud]:
    """The file's x, y, z (float64 as :func:`read` returns them: the file's frame, z up) in chunks of at
    most ``chunk_points`` rows, in file order, each a :class:`PointCloud` without attributes (``crs``,
    ``columns`` and ``z_positive`` as in ``read_points``). Memory: one parsed chunk, roughly 150 bytes per
    point. A bad line in any chunk raises the error :func:`read` gives for the whole file; the vertical
    checks (``core.apply_z_positive``) look at the first chunk."""
    import pandas as pd

    p, where, gz, layout, names, axes, merged = _open_layout(path, crs, columns, z_positive)
    options = {"crs": crs, "read": {"columns": columns, "z_positive": z_positive}}
    n, checked = 0, False
    try:
        with pd.read_csv(p, chunksize=chunk_points, **_csv_options(layout, gz)) as reader:
            for df in reader:
                if df.shape[1] != len(names):
                    _reader_error(p, crs, f"a line after point {n} has {df.shape[1]} columns, not {len(names)}",
                                  **options["read"])
                if not checked and df.isna().to_numpy().any():
                    # Short lines read as NaN, but so does a legitimate 'nan' attribute: let the whole-file
                    # reader decide once (it raises naming the line, or accepts the file).
                    read(p, crs=crs, **options["read"])
                    checked = True
                xyz = _chunk_xyz(df, axes.xyz, p, n, options)
                if n == 0:
                    apply_z_positive(xyz[:, 2], axes.down, ambiguous=axes.ambiguous,
                                     explicit=z_positive is not None, where=where)
                elif axes.down:
                    np.negative(xyz[:, 2], out=xyz[:, 2])
                n += len(xyz)
                yield PointCloud(xyz, crs=merged, source=where)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, OSError, EOFError, UnicodeError) as exc:
        _reader_error(p, crs, f"cannot parse the file ({exc})", **options["read"])
    if n == 0:
        raise PointCloudError(f"{where}: no points")
    _check_count(layout, n, where)
