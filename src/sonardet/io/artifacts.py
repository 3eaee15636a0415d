"""Reading files back with errors that name the file: the cached artifacts of the workflow (scene and
template ``.npz``, tiles, scene / detection / metrics / object JSON, meshes, checkpoints) and anything
else a step reads.

A file that cannot be read raises :class:`FileReadError` (a ``ValueError``) whose message starts with
the path, names the member (``.npz`` entry) or the line (JSON, text) where there is one, says what was
found (truncated, not UTF-8, not JSON, ...) and how to get a good file again: a file the workflow
wrote is deleted and rebuilt by rerunning the step that writes it (:func:`rebuild_hint`).

numpy raises ``zipfile.BadZipFile`` for a truncated ``.npz``, ``json`` a ``JSONDecodeError`` without
the file and ``pathlib`` a ``UnicodeDecodeError`` without the file: the readers here turn these into
one error type with the file named.
"""

from __future__ import annotations

import json
import pickle
import struct
import zipfile
import zlib
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["READ_ERRORS", "FileReadError", "read_json_file", "read_npz", "read_text_file", "reading",
           "rebuild_hint"]

#: Exceptions a damaged file makes the libraries raise (numpy, zipfile, zlib, json, pickle, struct,
#: OS errors other than a missing file are added by :func:`reading`).
READ_ERRORS: tuple[type[BaseException], ...] = (
    zipfile.BadZipFile, zlib.error, EOFError, ValueError, KeyError, IndexError, TypeError, UnicodeError,
    pickle.UnpicklingError, struct.error, RuntimeError,
)


class FileReadError(ValueError):
    """A file cannot be read (truncated, corrupt, wrong format); the message names the file, the member or
    line where there is one, and the fix."""


def rebuild_hint(path) -> str:
    """What to do about a damaged file the workflow wrote: delete it and rerun the step that writes it."""
    return f"delete it and rerun the step that writes it to rebuild it (in the workflow: `rm {path}`, then run snakemake again)"


def _describe(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


@contextmanager
def reading(path, what: str, member: str | None = None, hint: str | None = None) -> Iterator[None]:
    """Turn the errors a damaged file raises inside the block into a :class:`FileReadError` naming
    `path`, the kind of file (`what`, e.g. "scene soundings file"), the `member` if given, and `hint`
    (default :func:`rebuild_hint`). A missing file stays a FileNotFoundError (with the path); errors
    that already are FileReadError pass unchanged."""
    try:
        yield
    except FileReadError:
        raise
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{path}: no such file ({what})") from exc
    except (*READ_ERRORS, OSError) as exc:
        where = f"{path}" + (f", entry {member!r}" if member else "")
        raise FileReadError(f"{where}: cannot read this {what} ({_describe(exc)}); the file is truncated or "
                            f"damaged: {hint or rebuild_hint(path)}") from exc


def read_npz(path, what: str, required: Iterable[str] = (), hint: str | None = None) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file (name -> array, read eagerly, no pickles), each member read on its
    own so that a damaged one is named. Raises :class:`FileReadError` for a file that is not a zip
    archive (garbage, truncated: its directory is at the end), a damaged member (CRC, short data) or a
    missing `required` member; FileNotFoundError when it does not exist."""
    path = Path(path)
    with reading(path, what, hint=hint):
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise FileReadError(f"{path}: holds a single array, expected an .npz archive ({what}): "
                                f"{hint or rebuild_hint(path)}")
    out = {}
    with z:
        for name in z.files:
            with reading(path, what, member=name, hint=hint):
                out[name] = z[name]
    missing = [k for k in required if k not in out]
    if missing:
        raise FileReadError(f"{path}: no entry {', '.join(map(repr, missing))} (it holds {sorted(out)}); not a "
                            f"complete {what}: {hint or rebuild_hint(path)}")
    return out


def read_text_file(path, what: str, hint: str | None = None) -> str:
    """A UTF-8 text file's content; bytes that are not UTF-8 raise :class:`FileReadError` naming the
    file, the line and the byte offset."""
    path = Path(path)
    with reading(path, what, hint=hint):
        data = path.read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise FileReadError(f"{path}: line {line} (byte {exc.start}): not UTF-8 text ({exc.reason}, byte "
                            f"{data[exc.start:exc.start + 1]!r}); not a valid {what}: {hint or rebuild_hint(path)}"
                            ) from None


def read_json_file(path, what: str, hint: str | None = None) -> Any:
    """A JSON document from a UTF-8 file; a damaged file raises :class:`FileReadError` naming the file
    and the line and column of the problem (empty, truncated, not UTF-8, not JSON)."""
    path = Path(path)
    text = read_text_file(path, what, hint)
    if not text.strip():
        raise FileReadError(f"{path}: empty file, expected a {what} (JSON): {hint or rebuild_hint(path)}")
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileReadError(f"{path}: line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg}); the "
                            f"{what} is truncated or damaged: {hint or rebuild_hint(path)}") from None

