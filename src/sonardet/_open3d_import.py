"""Import Open3D without loading its plotly/dash viewer until someone uses it.

``import open3d`` imports ``open3d.visualization``, which imports ``draw_plotly`` and with it the
web frameworks ``dash`` and ``plotly``: about 0.3 s of a 0.6 s import (measured on the project's
2-core VM with ``python -X importtime -c "import open3d"``), paid by every workflow job that touches
Open3D (the scene simulations, the model-based detections, the template scans), although sonardet
never draws with plotly.

:func:`install` (called by ``sonardet/__init__.py``, so before any sonardet module imports Open3D)
puts a finder first on ``sys.meta_path`` that answers for ``open3d.visualization.draw_plotly`` alone
with a stand-in module. Its three functions that ``open3d.visualization`` re-exports
(``get_plotly_fig``, ``draw_plotly``, ``draw_plotly_server``) load the real module when first called
and then call it; any other attribute of the stand-in loads it too. Nothing of Open3D changes but
when the viewer's dependencies are imported. Open3D offers no switch for this (its
``visualization/__init__.py`` imports the viewer unconditionally), hence the finder.

``SONARDET_EAGER_OPEN3D=1`` in the environment turns the stand-in off.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import os
import sys
import threading
import types

__all__ = ["MODULE", "install", "load_real"]

#: The Open3D submodule that is loaded lazily.
MODULE = "open3d.visualization.draw_plotly"
#: Its names that ``open3d.visualization`` imports at start-up (``from .draw_plotly import ...``).
_REEXPORTED = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")
#: One thread loads the real module; another asking meanwhile waits for it.
_LOCK = threading.Lock()


def load_real() -> types.ModuleType:
    """The real ``open3d.visualization.draw_plotly`` module, imported now if only the stand-in was."""
    with _LOCK:
        return _load_real()


def _load_real() -> types.ModuleType:
    mod = sys.modules.get(MODULE)
    if mod is not None and not getattr(mod, "__sonardet_stand_in__", False):
        return mod
    parent = sys.modules["open3d.visualization"]
    spec = importlib.machinery.PathFinder.find_spec(MODULE, parent.__path__)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot find {MODULE} in {list(parent.__path__)}")
    real = importlib.util.module_from_spec(spec)
    # Importing a submodule sets it as an attribute of its package; the package's attribute
    # ``draw_plotly`` is the function of that name (re-exported), so it is put back afterwards.
    saved = {name: getattr(parent, name) for name in _REEXPORTED if hasattr(parent, name)}
    sys.modules[MODULE] = real
    try:
        spec.loader.exec_module(real)
    except BaseException:
        if mod is not None:
            sys.modules[MODULE] = mod
        raise
    finally:
        for name, value in saved.items():
            setattr(parent, name, value)
    return real


def _forwarder(name: str):
    def call(*args, **kwargs):
        return getattr(load_real(), name)(*args, **kwargs)

    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"Open3D's ``{MODULE}.{name}``, loaded on first call (see sonardet._open3d_import)."
    return call


def _module_getattr(name: str):
    if name.startswith("__"):
        raise AttributeError(name)
    return getattr(load_real(), name)


class _Loader(importlib.abc.Loader):
    def create_module(self, spec):
        return None

    def exec_module(self, module):
        module.__sonardet_stand_in__ = True
        module.__getattr__ = _module_getattr
        for name in _REEXPORTED:
            setattr(module, name, _forwarder(name))


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path, target=None):
        if fullname != MODULE:
            return None
        return importlib.machinery.ModuleSpec(fullname, _Loader(), origin="sonardet stand-in")


def install() -> bool:
    """Put the finder first on ``sys.meta_path`` (once); returns whether the stand-in is active.

    It is not installed when Open3D's visualization is already imported, or when the environment
    sets ``SONARDET_EAGER_OPEN3D=1``."""
    if os.environ.get("SONARDET_EAGER_OPEN3D", "") not in ("", "0"):
        return False
    if any(isinstance(f, _Finder) for f in sys.meta_path):
        return True
    if "open3d.visualization" in sys.modules:
        return False
    sys.meta_path.insert(0, _Finder())
    return True
