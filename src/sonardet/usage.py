"""A workflow job's exact CPU record: written by the job when it ends (`sonardet.workflow`), read by
the run's time line (`sonardet.report.timeline`). Standard library only, so every job can afford it.

Snakemake's benchmark files sample a job's CPU time (every second for its first 30 s, then every
30 s), so a long job's `cpu_time` misses up to 30 s; the record a job writes at its end counts all
of its CPU up to then, imports included (the interpreter's shutdown after it, a fraction of a
second, is not in it). The workflow's log and benchmark files share their relative paths
(`results/logs/X.log`, `results/benchmarks/X.tsv`); the record is `results/logs/X.usage.json`.

The record also holds when the job ended (``end_epoch_s``, seconds since the epoch, read from the
clock when it is written): the benchmark file's modification time says the same, but only until the
results are copied without their times (``cp -r``, most archive and sync tools by default), after
which every job seems to have ended when the copy was made.
"""

from __future__ import annotations

import json
import math
import resource
import sys
import time
from pathlib import Path

__all__ = ["compilations_note", "cpu_seconds", "job_cpu_seconds", "job_usage", "numba_compilations", "read_usage",
           "usage_path"]


def cpu_seconds(who: int = resource.RUSAGE_SELF) -> float:
    """User + system CPU seconds of this process (RUSAGE_SELF) or of its finished children (RUSAGE_CHILDREN)."""
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def job_cpu_seconds() -> float:
    """CPU seconds of this process so far (its imports included) plus those of its finished children
    (e.g. tile workers): what a job's record counts."""
    return cpu_seconds(resource.RUSAGE_SELF) + cpu_seconds(resource.RUSAGE_CHILDREN)


def usage_path(log_path) -> Path:
    """Where the job with log `log_path` records its usage: the log's path with `.usage.json` for its suffix."""
    return Path(log_path).with_suffix(".usage.json")


def job_usage(threads: int, startup_cpu_s: float | None = None, jit: dict | None = None) -> dict:
    """This process's CPU seconds so far (its imports included) plus those of its finished children
    (e.g. tile workers), the threads the job was given and, when given, `startup_cpu_s`: the CPU
    seconds the process had spent when the job's own work began (interpreter start, Snakemake's
    script preamble, imports), and `jit`: its Numba compilations (`sonardet.jit.compile_stats`, as
    ``jit_n`` and ``jit_s``: wall seconds, single-threaded, so about their CPU seconds); and
    ``end_epoch_s``: now (s since the epoch), when the job ended."""
    rec = {"cpu_s": job_cpu_seconds(), "threads": int(threads), "end_epoch_s": time.time()}
    if startup_cpu_s is not None:
        rec["startup_cpu_s"] = float(startup_cpu_s)
    if jit is not None:
        rec["jit_n"], rec["jit_s"] = int(jit["n"]), float(jit["s"])
    return rec


def numba_compilations() -> dict:
    """This process's Numba compilations (`sonardet.jit.compile_stats`); none in a process that never
    imported the package's kernels (`sonardet.jit` is not imported here for that: it imports Numba)."""
    jit = sys.modules.get("sonardet.jit")
    return jit.compile_stats() if jit is not None else {"n": 0, "s": 0.0}


def compilations_note(jit: dict) -> str:
    """``"N Numba compilations took X s (...)"`` for a log or summary line, empty when there were none."""
    if not jit["n"]:
        return ""
    return (f"{jit['n']} Numba compilations took {jit['s']:.1f} s of it (the kernels' first use since they "
            "were installed or changed: cached on disk for later processes)")


def read_usage(path) -> dict | None:
    """The record at `path` as {"cpu_s", "threads" (>= 1), "startup_cpu_s", "jit_s" (Numba compilation
    seconds), "end_epoch_s" (when the job ended, s since the epoch); the last three NaN in records
    written before they were kept}, or None where there is none; a record that cannot be read is
    refused (ValueError naming the file)."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text())
        return {"cpu_s": float(rec["cpu_s"]), "threads": max(1, int(rec.get("threads", 1))),
                "startup_cpu_s": float(rec.get("startup_cpu_s", math.nan)), "jit_s": float(rec.get("jit_s", math.nan)),
                "end_epoch_s": float(rec.get("end_epoch_s", math.nan))}
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a job's usage record ({exc}); delete it and rerun its job") from None
