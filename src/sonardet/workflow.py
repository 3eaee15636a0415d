"""Glue for the thin Snakemake scripts: logging to the rule's log file and error reporting.

Takes the `snakemake` object duck-typed, so the library imports nothing from Snakemake.
"""

from __future__ import annotations

import logging
import sys
import time
import traceback
from contextlib import contextmanager


@contextmanager
def rule_logging(smk, name: str):
    """Send `logging` output of the library to the rule's log file (and stderr); log the exception
    and re-raise it on failure, so Snakemake reports the job as failed and removes its outputs."""
    handlers = [logging.StreamHandler(sys.stderr)]
    if getattr(smk, "log", None):
        handlers.append(logging.FileHandler(smk.log[0], mode="w"))
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s: %(message)s",
                        handlers=handlers, force=True)
    log = logging.getLogger(f"sonardet.{name}")
    t0 = time.perf_counter()
    try:
        yield log
    except Exception:
        log.error("failed:\n%s", traceback.format_exc())
        raise
    log.info("done in %.2f s", time.perf_counter() - t0)
