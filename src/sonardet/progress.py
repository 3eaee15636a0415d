"""Progress bars with an ETA for the long steps of the command line (simulating scenes, detecting over
tiles, exporting), through tqdm.

A bar is drawn on standard error only when it is a terminal and the caller enables it (``--quiet`` turns
it off); in a pipe, a log file or a Snakemake job nothing is drawn, so logs stay clean.
"""

from __future__ import annotations

from collections.abc import Iterable

__all__ = ["progress_bar"]


def progress_bar(iterable: Iterable | None = None, *, total: int | None = None, desc: str | None = None,
                 unit: str = "it", enabled: bool = True):
    """A tqdm bar over ``iterable`` (or a manual one with ``total`` steps, advanced with ``.update(n)``),
    showing the rate and the estimated time left; silent when ``enabled`` is false or standard error is
    not a terminal. Use it as an iterable or a context manager."""
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=None if enabled else True,
                dynamic_ncols=True, leave=False)
