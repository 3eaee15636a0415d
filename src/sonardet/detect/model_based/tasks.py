"""Independent pieces of one `ours` detection run on worker threads, in input order.

Within a round the hypotheses of different proposals do not depend on one another: each reads the
run's shared state (candidate points, KD-trees, which points are explained) and writes only its own
hypothesis. Their heavy parts release the GIL (the compiled grid ICP and coverage passes, KD-tree
queries, FFTs, NumPy on large arrays), so two threads overlap a good part of them; Open3D's ray
casting and voxel thinning and NumPy on small arrays hold it.

The result does not depend on the thread count: a piece gets its own statistics dict (`task_stats`),
the results come back in input order and the statistics are merged in that order (`merge_stats`).
Stage seconds of pieces run on threads are summed over the threads (they can add up to more than the
wall time of the stage). The pool is made per detector call (`worker_pool`), so no thread outlives a
call: a process that forks tile workers afterwards has none.

Written here because no library maps over a thread pool with per-task counters merged in order;
`concurrent.futures` gives the pool.
"""

from __future__ import annotations

import contextlib
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field


def task_stats() -> dict:
    """An empty statistics dict for one piece: the counters the hypothesis steps add to."""
    return {"icp_runs": 0, "icp_runs_by_kind": {}, "icp_declined": 0, "refits": 0,
            "seconds": {"proposals": 0.0, "registration": 0.0, "scoring": 0.0}}


def merge_stats(stats: dict, part: dict) -> None:
    """Add a piece's statistics (`task_stats`) to the run's `stats` (seconds in s)."""
    for key in ("icp_runs", "icp_declined", "refits"):
        stats[key] += part[key]
    for kind, n in part["icp_runs_by_kind"].items():
        stats["icp_runs_by_kind"][kind] = stats["icp_runs_by_kind"].get(kind, 0) + n
    for stage, s in part["seconds"].items():
        stats["seconds"][stage] = stats["seconds"].get(stage, 0.0) + s


#: The records of `recording` while one is active (None: not recording).
_RECORDS: list | None = None


@dataclass
class RoundRecord:
    """One `run_tasks` call: the piece function's qualified name, the number of items, the call's wall
    seconds and each piece's own seconds (in completion order)."""

    name: str
    items: int
    wall_s: float
    task_s: list = field(default_factory=list)


@contextlib.contextmanager
def recording():
    """Record every `run_tasks` call of this process while active; yields the list of `RoundRecord`s.
    For benchmarks (`benchmarks/detect_threads.py`): it times each piece, which the detections do not
    depend on."""
    global _RECORDS
    if _RECORDS is not None:
        raise RuntimeError("run_tasks is already being recorded")
    _RECORDS = records = []
    try:
        yield records
    finally:
        _RECORDS = None


def _timed(fn, times: list):
    def run(item, part):
        t = time.perf_counter()
        try:
            return fn(item, part)
        finally:
            times.append(time.perf_counter() - t)
    return run


def run_tasks(pool: ThreadPoolExecutor | None, fn, items: list, stats: dict | None = None) -> list:
    """[fn(item, piece_stats) for item in items], on `pool`'s threads when there is one and more than
    one item; each piece's statistics are merged into `stats` (when given) in input order. An exception
    of a piece is raised here."""
    if _RECORDS is not None:
        rec = RoundRecord(getattr(fn, "__qualname__", repr(fn)), len(items), 0.0)
        _RECORDS.append(rec)
        t = time.perf_counter()
        try:
            return _run_tasks(pool, _timed(fn, rec.task_s), items, stats)
        finally:
            rec.wall_s = time.perf_counter() - t
    return _run_tasks(pool, fn, items, stats)


def _run_tasks(pool, fn, items, stats):
    parts = [task_stats() for _ in items]
    if pool is None or len(items) < 2:
        out = [fn(item, part) for item, part in zip(items, parts)]
    else:
        out = [fut.result() for fut in [pool.submit(fn, item, part) for item, part in zip(items, parts)]]
    if stats is not None:
        for part in parts:
            merge_stats(stats, part)
    return out


#: Upper bound of `worker_pool`'s threads in this process (None: none); a tile worker process sets 1.
_THREAD_LIMIT: int | None = None


def limit_threads(n: int | None) -> None:
    """At most `n` worker threads per detection call in this process from now on (None: no bound). The
    survey's tile worker processes set 1, so `jobs` processes use `jobs` cores."""
    global _THREAD_LIMIT
    _THREAD_LIMIT = None if n is None else max(1, int(n))


@contextlib.contextmanager
def worker_pool(threads: int):
    """A thread pool of `threads` workers (at most the `limit_threads` bound) for one detection call
    (None for one thread), shut down on exit."""
    threads = int(threads)
    if threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    if _THREAD_LIMIT is not None:
        threads = min(threads, _THREAD_LIMIT)
    if threads == 1:
        yield None
        return
    with ThreadPoolExecutor(max_workers=threads, thread_name_prefix="sonardet-detect") as pool:
        yield pool
