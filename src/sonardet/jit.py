"""Numba, configured once for the whole package: import it from here (``from sonardet.jit import numba``).

Numba's default threading layer on Linux is GNU OpenMP, whose threads do not survive a fork: a process
that ran (or only set the thread count of) a parallel kernel could then not fork tile workers
(`sonardet detect --jobs`), and a forked worker's ``numba.set_num_threads`` would reach into the
OpenMP runtime PyTorch shares. The workqueue layer is fork-safe and enough for the package's kernels
(the SASA operators' batch-parallel loops, called from one thread; the detector's serial kernels).
A layer chosen with NUMBA_THREADING_LAYER wins.

Compilation: the package's kernels are compiled on their first call in a process and cached on disk
(``cache=True``: ``__pycache__`` beside the source, or NUMBA_CACHE_DIR), so the first jobs after an
install or a change of a kernel's source compile them and every later process loads them. Numba
reports how long that took nowhere; :func:`compile_stats` does (a listener on Numba's
``numba:compile`` event, which fires for compilations only, not for loads from the cache), and the
workflow's jobs and ``sonardet detect`` log it.
"""

from __future__ import annotations

import os
import threading
import time

import numba
from numba.core import event

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"

__all__ = ["compile_stats", "numba"]


class _CompileClock(event.Listener):
    """Counts and times this process's top-level Numba compilations: a kernel compiled while another
    compiles (a kernel it calls) is part of the outer one's time, not counted again."""

    def __init__(self):
        self._local = threading.local()
        self._lock = threading.Lock()
        self.n = 0
        self.seconds = 0.0

    def on_start(self, ev):
        self._local.__dict__.setdefault("starts", []).append(time.perf_counter())

    def on_end(self, ev):
        starts = self._local.__dict__.get("starts")
        if not starts:  # started before the listener was registered
            return
        t0 = starts.pop()
        if not starts:
            with self._lock:
                self.n += 1
                self.seconds += time.perf_counter() - t0


_CLOCK = _CompileClock()
event.register("numba:compile", _CLOCK)


def compile_stats() -> dict:
    """This process's Numba compilations so far: ``{"n": top-level compilations (one per kernel and
    argument types), "s": wall seconds they took}``; loads from the on-disk cache are not counted."""
    with _CLOCK._lock:
        return {"n": int(_CLOCK.n), "s": float(_CLOCK.seconds)}
