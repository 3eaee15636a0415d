"""Numba, configured once for the whole package: import it from here (``from sonardet.jit import numba``).

Numba's default threading layer on Linux is GNU OpenMP, whose threads do not survive a fork: a process
that ran (or only set the thread count of) a parallel kernel could then not fork tile workers
(`sonardet detect --jobs`), and a forked worker's ``numba.set_num_threads`` would reach into the
OpenMP runtime PyTorch shares. The workqueue layer is fork-safe and enough for the package's kernels
(the SASA operators' batch-parallel loops, called from one thread; the detector's serial kernels).
A layer chosen with NUMBA_THREADING_LAYER wins.
"""

from __future__ import annotations

import os

import numba

if "NUMBA_THREADING_LAYER" not in os.environ:
    numba.config.THREADING_LAYER = "workqueue"

__all__ = ["numba"]
