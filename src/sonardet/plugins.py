"""Plugins: Python modules the config's `plugins` key lists, imported before the config is validated
(by the workflow, by every job and by the CLI), so that they can register method families
(`sonardet.methods.register`), object classes (`sonardet.objects.classes.register`) or sensor
effects. An entry is a path to a `.py` file (absolute, or relative to the working directory) or an
importable module name. Importing the same entry twice runs it once.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from pathlib import Path

__all__ = ["PluginError", "load_plugins"]

_LOADED: dict[str, str] = {}


class PluginError(ValueError):
    """A plugin could not be found or failed to import; the message names the config entry."""


def _module_name(path: Path) -> str:
    digest = hashlib.sha1(str(path).encode()).hexdigest()[:8]
    return f"sonardet_plugin_{path.stem}_{digest}"


def _load_file(path: Path, where: str) -> str:
    name = _module_name(path)
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise PluginError(f"{where}: {path} is not an importable Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:
        sys.modules.pop(name, None)
        raise PluginError(f"{where}: importing {path} failed: {type(exc).__name__}: {exc}") from exc
    return name


def load_plugins(entries, key: str = "plugins") -> list[str]:
    """Import each plugin of `entries` (see module docstring) once; returns the module names.

    Raises PluginError naming `{key}[i]` for a missing file, an unknown module or an import error.
    """
    names = []
    for i, entry in enumerate(entries or []):
        where = f"{key}[{i}] ({entry!r})"
        if not isinstance(entry, str) or not entry.strip():
            raise PluginError(f"{where}: expected a path to a .py file or a module name")
        is_file = entry.endswith(".py") or "/" in entry or "\\" in entry
        ident = str(Path(entry).resolve()) if is_file else entry
        if ident in _LOADED:
            names.append(_LOADED[ident])
            continue
        if is_file:
            path = Path(entry).resolve()
            if not path.is_file():
                raise PluginError(f"{where}: no such file {path} (relative paths are relative to the working "
                                  "directory)")
            name = _load_file(path, where)
        else:
            try:
                importlib.import_module(entry)
            except ImportError as exc:
                raise PluginError(f"{where}: cannot import module {entry!r}: {exc}") from exc
            name = entry
        _LOADED[ident] = name
        names.append(name)
    return names
