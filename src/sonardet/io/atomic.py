"""Atomic file writes: a rule never leaves a half-written output behind.

* :func:`atomic_path`: one output through a temporary file beside it;
* :func:`atomic_outputs`: several outputs of one step, all or none: each is written to a temporary
  file of the *same name* in a hidden folder beside its target, and the files are moved into place
  only once every one of them has been written (a step that fails half way leaves the old outputs,
  or none, never a mix);
* :func:`check_writable`: every output path checked before a long computation starts, errors naming
  the path as the user gave it.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = ["OutputError", "atomic_outputs", "atomic_path", "atomic_write_bytes", "atomic_write_text",
           "check_writable"]


class OutputError(OSError):
    """An output path cannot be written (the message names the path and why)."""


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


@contextmanager
def atomic_path(path):
    """Yield a temporary path in the target's directory; on success it replaces `path`, on error it is
    removed. The temporary name keeps the target's suffixes so writers that dispatch on them work."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix="".join(path.suffixes) or ".tmp", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates 0600; give the output the permissions a plain open() would.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_bytes(path, data: bytes) -> None:
    """Write bytes to `path` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path, text: str) -> None:
    """Write text (UTF-8) to `path` atomically."""
    atomic_write_bytes(path, text.encode("utf-8"))


def _why_not_writable(path: Path) -> str | None:
    """Why `path` cannot be written as an output file (None: it can)."""
    if path.is_dir():
        return "is a directory"
    if path.exists() and not os.access(path, os.W_OK):
        return "exists and is read-only"
    parent = path.parent
    while not parent.exists():  # the nearest existing ancestor must let us create the missing folders
        if parent.parent == parent:
            break
        parent = parent.parent
    if not parent.is_dir():
        return f"{parent} is not a directory"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"the folder {parent} is not writable"
    return None


def check_writable(paths: Sequence, label: str = "output") -> None:
    """Raise :class:`OutputError` naming every path of `paths` (None entries skipped) that cannot be
    written: a directory, an existing read-only file (not overwritten, although a rename could), or
    a folder (or the nearest existing ancestor of a missing folder) without write permission (outputs
    are renamed into place, which needs the folder). Call it before a long computation whose results
    would otherwise be lost at the end."""
    problems = []
    for p in paths:
        if p is None:
            continue
        why = _why_not_writable(Path(p))
        if why is not None:
            problems.append(f"{label} {p}: cannot be written ({why})")
    if problems:
        raise OutputError("; ".join(problems))


def _publish(staged: list[tuple[Path, Path]]) -> None:
    """Move each staged file onto its target (`os.replace`), with the permissions of a plain open()."""
    mode = 0o666 & ~_umask()
    for tmp, target in staged:
        if not tmp.is_file():
            raise OutputError(f"{target}: the step finished without writing this output")
    for tmp, target in staged:
        os.chmod(tmp, mode)
        os.replace(tmp, target)


def _named(exc: OSError, staged: list[tuple[Path, Path]]) -> OSError:
    """An OSError about a staged file, reworded to name the output the user asked for (not the temporary
    file); other errors unchanged."""
    name = getattr(exc, "filename", None)
    if not name:
        return exc
    p = Path(name)
    for tmp, target in staged:
        if p == tmp or (p.parent == tmp.parent and p.name.startswith(f".{target.stem}.")):
            return OutputError(exc.errno, f"{target}: cannot be written ({exc.strerror or exc})")
    return exc


@contextmanager
def atomic_outputs(paths: Sequence) -> Iterator[list[Path]]:
    """All outputs of one step or none: yields one temporary path per target in `paths`, each with the
    target's own file name (so writers that check the name or dispatch on the suffix work) in a hidden
    folder beside the target. When the block ends without error and every temporary file exists, they
    replace their targets (`os.replace`, same file system); on any error, or when one was not written,
    they are all removed and the targets are left as they were. Parent folders are created.

    Usage::

        with atomic_outputs([dets_path, stats_path]) as (dets_tmp, stats_tmp):
            write_detections(dets_tmp, ...)
            atomic_write_text(stats_tmp, ...)

    The moves themselves are not one transaction: they happen only after everything was written, one
    rename each, so a failure there needs the file system to fail between two renames in one folder.
    """
    targets = [Path(p) for p in paths]
    if len({t.resolve() for t in targets}) != len(targets):
        raise ValueError(f"atomic_outputs: the same output listed twice in {[str(t) for t in targets]}")
    stage_dirs: dict[Path, Path] = {}
    try:
        staged = []
        for t in targets:
            parent = t.parent
            if parent not in stage_dirs:
                parent.mkdir(parents=True, exist_ok=True)
                stage_dirs[parent] = Path(tempfile.mkdtemp(prefix=".staging.", dir=parent))
            staged.append((stage_dirs[parent] / t.name, t))
        try:
            yield [tmp for tmp, _ in staged]
        except OSError as exc:
            raise _named(exc, staged) from exc
        _publish(staged)
    finally:
        for d in stage_dirs.values():
            shutil.rmtree(d, ignore_errors=True)
