"""The time line of a workflow run from its Snakemake benchmark files: when each job ran, the wall time,
the total job time, the idle core-time, the chain of jobs that set the end time, and a Gantt figure.

Each benchmark file (`{root}/{rule}/{wildcards...}.tsv`) holds a job's wall seconds (`s`) and CPU
seconds (`cpu_time`). A job ended when its usage record says (`end_epoch_s`, below), else at the
file's modification time (records written before the end time was kept), and started `s` seconds
before. (Snakemake records no start times; the main log has them only to the second.) A copy of the
results that did not keep the files' times (`cp -r`) moves every modification time to the copy's:
the record's time survives it; a run timed from such files alone holds more job core-time than its
cores had, which the summary names instead of reporting it as the run's. Meaningful for a run that
made every job (a fresh run); after a partial rerun the old jobs keep their old times.

Snakemake samples `cpu_time` (every second for a job's first 30 s, then every 30 s), so a long job's
figure misses up to 30 s: in a default run the sampled CPU summed to 77 of the jobs' 90 minutes. Each
job of this workflow also records its exact CPU seconds and threads at its end, beside its log
(`sonardet.usage`: `{logs}/{rule}/{wildcards...}.usage.json`, the benchmark file's relative path);
that record is used where it exists, the sampled figure elsewhere.

Two different "idle" figures: the idle core-time is the core-time no job held (cores x wall minus
each job's seconds x its threads: what the scheduler left unused), and the job core-time off the
recorded CPU is what the jobs held but did not compute by their records (waiting for files, the GIL
or a core that another job's threads took, and each interpreter's shutdown after its record).

Job time per method: each job is counted for the detection method it trains, runs, evaluates or
ablates (`job_method`: the method is in the benchmark path of `train`, `detect_dataset`,
`detect_scenes` and `evaluate`, and in the ablation point's file for `ablation`; a job shared by
several methods counts for the first, whose stages the others reuse), the scene simulations as
`(scenes)` and every other job as `(other)`. Methods are grouped by their name without a trailing
`_{number}` (`sasa_25`, `sasa_100` -> `sasa`; `sasa_dr_100` -> `sasa_dr`).

The chain reported is the *blocking chain*: from the job that ended last, each step back is the job
that ended last before this one started, i.e. what this job waited for (a dependency or a free
core). Its total is the run's wall time minus the gaps in the chain.
"""

from __future__ import annotations

import json
import math
import re
import resource
import time
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib import colormaps

from ..usage import cpu_seconds, read_usage, usage_path
from .style import new_figure, write_figure

__all__ = ["PROCESS_FILE", "blocking_chain", "critical_path", "job_method", "method_group", "plot_gantt",
           "process_usage", "read_benchmarks", "read_point_methods", "read_process_usage", "run_summary",
           "summary_lines"]

#: Where the workflow records its Snakemake process's own usage (under the benchmark folder), written
#: by the Snakefile's onsuccess / onerror handlers.
PROCESS_FILE = "snakemake_process.json"
#: Rules whose benchmark path names the method(s) right after the rule: train/{method},
#: detect_dataset/{method}[+{method}...]/{dataset}, detect_scenes/{method}[+{method}...]/{dataset},
#: evaluate/{method}/{dataset}.
METHOD_RULES = ("train", "detect_dataset", "detect_scenes", "evaluate")
#: Rules that simulate scenes (the `(scenes)` group of `job_method`).
SCENE_RULES = ("simulate_scene", "simulate_scenes")
#: Job core-time above cores x wall by more than this share is impossible for a run on that many
#: cores: the summary flags it (`run_summary`, key ``overfull``) rather than report it as the run's.
OVERFULL_TOLERANCE = 0.02


def read_point_methods(results) -> dict:
    """Ablation point name -> its method (`results/ablation/points/{point}.json`, key `method`); empty
    where the run made no ablation. A point file that is not JSON raises ValueError naming it."""
    out = {}
    for p in sorted((Path(results) / "ablation" / "points").glob("*.json")):
        try:
            out[p.stem] = str(json.loads(p.read_text())["method"])
        except (ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{p}: not an ablation point record with a 'method' ({exc!r}); delete it and rerun "
                             "its ablation job") from None
    return out


def job_method(job: str, point_methods: dict | None = None) -> str:
    """The method a job (benchmark path without `.tsv`, e.g. `train/sasa_100`) is counted for (module
    doc): the first method of its path for the method rules, the ablation point's method, `(scenes)`
    for a scene simulation, `(other)` for the rest."""
    parts = job.split("/")
    if parts[0] in METHOD_RULES and len(parts) > 1:
        return parts[1].split("+")[0]
    if parts[0] == "ablation" and len(parts) > 1 and parts[1] in (point_methods or {}):
        return point_methods[parts[1]]
    return "(scenes)" if parts[0] in SCENE_RULES else "(other)"


def method_group(method: str) -> str:
    """A method's group: its name without a trailing `_{number}` (`sasa_100` -> `sasa`)."""
    return re.sub(r"_\d+$", "", method)


def read_benchmarks(root, logs=None) -> pd.DataFrame:
    """Every `{root}/**/*.tsv` benchmark file as a row: rule (first folder under root), job (the rest of
    the path), start and end (s, epoch), seconds (wall), cpu_s, cpu_exact (True where the job's usage
    record under `logs` gave cpu_s, False where it is Snakemake's sampled `cpu_time`), threads (from
    the record, else 1), max_rss_mb, method (`job_method`, the ablation points read from the results
    folder that holds `root`), end_from ('record' where the job's usage record gave its end time,
    'file' where the benchmark file's modification time did); sorted by start. logs: the run's log
    folder (default: `logs` beside `root`). A missing `root` raises FileNotFoundError naming it."""
    rows = []
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no benchmark folder here; run the workflow first (snakemake --cores 2) "
                                "or name the results folder of a run")
    logs = root.parent / "logs" if logs is None else Path(logs)
    point_methods = read_point_methods(root.parent)
    for p in sorted(root.rglob("*.tsv")):
        try:
            df = pd.read_csv(p, sep="\t")
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
            raise ValueError(f"{p}: not a Snakemake benchmark file ({exc}); delete it and rerun its job") from None
        if len(df) == 0 or "s" not in df.columns:
            continue
        rel = p.relative_to(root)
        s = float(df["s"].iloc[0])
        cpu = pd.to_numeric(df.get("cpu_time", pd.Series([np.nan])), errors="coerce").iloc[0]
        rss = pd.to_numeric(df.get("max_rss", pd.Series([np.nan])), errors="coerce").iloc[0]
        rec = read_usage(usage_path(logs / rel.with_suffix(".log")))  # the job's log mirrors its benchmark file
        from_record = rec is not None and math.isfinite(rec["end_epoch_s"])
        end = rec["end_epoch_s"] if from_record else p.stat().st_mtime
        job = rel.with_suffix("").as_posix()
        rows.append({"rule": rel.parts[0] if len(rel.parts) > 1 else rel.stem,
                     "job": job, "start": end - s, "end": end, "seconds": s,
                     "cpu_s": float(cpu) if rec is None else rec["cpu_s"], "cpu_exact": rec is not None,
                     "threads": 1 if rec is None else rec["threads"],
                     "startup_cpu_s": math.nan if rec is None else rec["startup_cpu_s"],
                     "jit_s": math.nan if rec is None else rec["jit_s"], "max_rss_mb": float(rss),
                     "method": job_method(job, point_methods), "end_from": "record" if from_record else "file"})
    df = pd.DataFrame(rows, columns=["rule", "job", "start", "end", "seconds", "cpu_s", "cpu_exact", "threads",
                                     "startup_cpu_s", "jit_s", "max_rss_mb", "method", "end_from"])
    return df.sort_values(["start", "job"]).reset_index(drop=True)


def process_usage() -> dict:
    """This process's own CPU seconds (user + system; for the Snakemake process: scheduling, the DAG,
    input functions, file checks, `run:` blocks) and the CPU seconds of its finished children (the
    jobs, each a subprocess), its wall seconds since it started, and the share of one core its own
    CPU is of that wall time. Read with :mod:`resource` and psutil (a Snakemake dependency). On a
    cluster profile the jobs run elsewhere: the children are then the local jobs only."""
    import psutil  # imported here: only the workflow's end handlers need it

    wall = time.time() - psutil.Process().create_time()
    own_cpu = cpu_seconds(resource.RUSAGE_SELF)
    return {"own_cpu_s": own_cpu, "children_cpu_s": cpu_seconds(resource.RUSAGE_CHILDREN), "wall_s": wall,
            "own_core_share": own_cpu / wall if wall > 0 else math.nan,
            "own_max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def read_process_usage(root) -> dict | None:
    """The Snakemake process's usage that the last run wrote into the benchmark folder ``root``, or None."""
    path = Path(root) / PROCESS_FILE
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"{path}: not the workflow's process record ({exc}); delete it and rerun") from None


#: Seconds by which a job may seem to start before the job it followed ended. A job's end is its usage
#: record's time, written before its interpreter exits, and its start that end less the benchmark's
#: wall seconds, which include the exit: so the start comes out early by the exit (up to 1.0 s in the
#: b8986cc run, where a SASA training seemed to start 1.02 s before the scene job it read had ended).
EXIT_SLACK_S = 2.0


def blocking_chain(df: pd.DataFrame, slack_s: float = EXIT_SLACK_S) -> pd.DataFrame:
    """The blocking chain (see module doc), in time order: from the last job back, each predecessor is
    the job that ended last at most `slack_s` after this one started."""
    if df.empty:
        return df.copy()
    chain = [int(df["end"].idxmax())]
    while True:
        start = df.loc[chain[-1], "start"]
        before = df[(df["end"] <= start + slack_s) & (df.index != chain[-1]) & (df["start"] < start)]
        if before.empty:
            break
        chain.append(int(before["end"].idxmax()))
    return df.loc[list(reversed(chain))].reset_index(drop=True)


def critical_path(df: pd.DataFrame, deps: dict) -> tuple[list[str], float]:
    """The dependency critical path: the chain of jobs, each depending on the one before
    (deps: job -> the jobs whose outputs it reads), with the largest sum of measured wall seconds;
    (jobs in order, seconds). Jobs without a benchmark count 0 s."""
    secs = dict(zip(df["job"], df["seconds"]))
    order = sorted(set(deps) | {d for ds in deps.values() for d in ds} | set(secs),
                   key=lambda j: dict(zip(df["job"], df["start"])).get(j, -1.0))
    best: dict[str, tuple[float, str | None]] = {}

    def longest(j, stack=()):
        if j in best:
            return best[j][0]
        if j in stack:
            raise ValueError(f"dependency cycle at {j}")
        pre = [(longest(d, stack + (j,)), d) for d in deps.get(j, ())]
        top = max(pre, default=(0.0, None))
        best[j] = (top[0] + float(secs.get(j, 0.0)), top[1])
        return best[j][0]

    for j in order:
        longest(j)
    end = max(best, key=lambda j: best[j][0])
    path = [end]
    while best[path[-1]][1] is not None:
        path.append(best[path[-1]][1])
    return list(reversed(path)), best[end][0]


def _jit_summary(df: pd.DataFrame) -> dict:
    """Seconds of Numba compilation summed over the jobs whose usage record has it (``jit_s``), the
    jobs that compiled anything (``jit_jobs``) and those that recorded it (``jit_recorded_jobs``)."""
    jit = df["jit_s"]
    return {"jit_s": float(np.nansum(jit)), "jit_jobs": int((jit > 0).sum()), "jit_recorded_jobs": int(jit.notna().sum())}


def run_summary(df: pd.DataFrame, cores: int) -> dict:
    """Wall time (s, first start to last end), total job time (s, sum of wall seconds), job core-time
    (s, each job's wall seconds x its threads), idle core-time (cores x wall - job core-time, s: no job
    on the core), utilisation (job core-time / (cores x wall)), CPU time (s; `cpu_exact_jobs` of the
    jobs from their usage records, the others sampled by Snakemake, see the module doc) and the job
    core-time not spent on a CPU, the CPU seconds spent before the jobs' own work (interpreter start,
    imports; summed over the `startup_jobs` whose record has it), the seconds of Numba compilation
    (`_jit_summary`), jobs, the blocking chain's rules and
    seconds, the seconds per rule (sum, sorted) and per method group (`method_group` of the `method`
    column where `df` has one: jobs, wall and CPU seconds, the methods in it; sorted), how many jobs
    were timed by their benchmark file's modification time (``ends_from_files``) and whether the jobs
    held more core-time than `cores` had over the wall time (``overfull``: more cores than `cores`,
    or modification times a copy reset; module doc)."""
    if df.empty:
        return {"jobs": 0}
    wall = float(df["end"].max() - df["start"].min())
    cpu = float(np.nansum(df["cpu_s"]))
    core = float((df["seconds"] * df["threads"]).sum())
    chain = blocking_chain(df)
    per_rule = df.groupby("rule").agg(count=("seconds", "count"), sum=("seconds", "sum"), max=("seconds", "max"),
                                      cpu=("cpu_s", "sum"), startup=("startup_cpu_s", "sum"), jit=("jit_s", "sum"),
                                      ).sort_values("sum", ascending=False)
    per_method = {}
    if "method" in df.columns:
        groups = df.assign(group=df["method"].map(method_group)).groupby("group")
        agg = groups.agg(jobs=("seconds", "count"), sum_s=("seconds", "sum"), cpu_s=("cpu_s", "sum"),
                         methods=("method", lambda m: sorted(set(m))))
        agg = agg.rename_axis("group").reset_index().sort_values(["sum_s", "group"], ascending=[False, True])
        per_method = {r.group: {"jobs": int(r.jobs), "sum_s": float(r.sum_s), "cpu_s": float(r.cpu_s),
                                "methods": list(r.methods)} for r in agg.itertuples()}
    return {"jobs": int(len(df)), "cores": int(cores), "wall_s": wall, "job_s": float(df["seconds"].sum()),
            "job_core_s": core, "idle_core_s": max(0.0, cores * wall - core),
            "utilisation": core / (cores * wall) if wall > 0 else math.nan,
            "ends_from_files": int((df["end_from"] != "record").sum()),
            "overfull": bool(core > cores * wall * (1.0 + OVERFULL_TOLERANCE)),
            "cpu_s": cpu, "cpu_exact_jobs": int(df["cpu_exact"].sum()), "job_core_off_cpu_s": max(0.0, core - cpu),
            "startup_cpu_s": float(np.nansum(df["startup_cpu_s"])),
            "startup_jobs": int(df["startup_cpu_s"].notna().sum()),
            **_jit_summary(df),
            "chain": [{"job": r.job, "rule": r.rule, "start_s": float(r.start - df["start"].min()),
                       "seconds": float(r.seconds)} for r in chain.itertuples()],
            "chain_s": float(chain["seconds"].sum()),
            "per_rule": {k: {"jobs": int(v["count"]), "sum_s": float(v["sum"]), "max_s": float(v["max"]),
                             "cpu_s": float(v["cpu"]), "startup_cpu_s": float(v["startup"]), "jit_s": float(v["jit"])}
                         for k, v in per_rule.iterrows()},
            "per_method": per_method}


def summary_lines(s: dict) -> list[str]:
    """The headline of a `run_summary`: wall, job time and idle core-time; CPU in jobs and where it
    came from; the job time per method group (where the summary has it); the blocking chain's rules,
    always the last line (minutes)."""
    if not s.get("jobs"):
        return ["no benchmark files: no jobs ran"]
    return [f"{s['jobs']} jobs on {s['cores']} cores: wall {s['wall_s'] / 60:.1f} min, job time {s['job_s'] / 60:.1f} "
            f"min, idle core-time {s['idle_core_s'] / 60:.1f} min (no job on the core; {100 * s['utilisation']:.0f} % "
            "of the core-time held by jobs)",
            *([f"NOT A TIME LINE OF THIS RUN: its jobs held {s['job_core_s'] / 60:.1f} core-minutes in "
               f"{s['wall_s'] / 60:.1f} min on {s['cores']} cores, more than the cores had. Either the run had more "
               f"cores (pass them: --cores), or its times are lost: {s['ends_from_files']} of "
               f"{s['jobs']} jobs are timed by their benchmark file's modification time, which a copy that did "
               "not keep the files' times (cp -r) resets (copy with cp -a, cp -p or rsync -t)"]
              if s.get("overfull") else []),
            f"CPU in jobs {s['cpu_s'] / 60:.1f} min ({s['cpu_exact_jobs']} of {s['jobs']} jobs from their own exact "
            "records, the rest from Snakemake's sampled cpu_time, which misses up to 30 s a job), "
            f"{s['job_core_off_cpu_s'] / 60:.1f} min of job core-time off that CPU (waiting, interpreter exits)",
            *([f"of that CPU, {s['startup_cpu_s'] / 60:.1f} min before the jobs' own work (interpreter start, imports; "
               f"{s['startup_jobs']} jobs recorded it)"] if s.get("startup_jobs") else []),
            *([f"of that CPU, {s['jit_s'] / 60:.1f} min compiling Numba kernels, in {s['jit_jobs']} jobs (their first use "
               f"since they were installed or changed; cached on disk after; {s['jit_recorded_jobs']} jobs recorded it)"]
              if s.get("jit_recorded_jobs") else []),
            *(["job time per method: " + ", ".join(f"{k} {v['sum_s'] / 60:.1f} min"
                                                    for k, v in s["per_method"].items())]
              if s.get("per_method") else []),
            f"blocking chain ({s['chain_s'] / 60:.1f} min of jobs): " + " -> ".join(c["rule"] for c in s["chain"])]


def gantt_lanes(df: pd.DataFrame, slack_s: float = EXIT_SLACK_S) -> list[int]:
    """The lane (0, 1, ...) of each job of `df` (in its row order, by start) in a Gantt chart: the first
    lane whose last job ended at most `slack_s` after this one started (EXIT_SLACK_S: a job seems to
    start early by its predecessor's interpreter exit), else a new lane. So a lane beyond the cores
    shows jobs that ran together for longer than that slack (threads beyond the cores), not the
    recorded times' skew."""
    lanes_end: list[float] = []
    lane = []
    for r in df.itertuples():
        free = [i for i, e in enumerate(lanes_end) if e <= r.start + slack_s]
        i = free[0] if free else len(lanes_end)
        if i == len(lanes_end):
            lanes_end.append(r.end)
        else:
            lanes_end[i] = r.end
        lane.append(i)
    return lane


def plot_gantt(df: pd.DataFrame, out_png, cores: int, title: str = "workflow run") -> Path:
    """A Gantt chart: one bar per job on the lane (of `cores`, plus overflow lanes for threads beyond)
    it ran in, coloured by rule, the blocking chain outlined; x in minutes from the first start."""
    t0 = df["start"].min() if len(df) else 0.0
    lane = gantt_lanes(df)
    n_lanes = max(lane) + 1 if lane else 0
    rules = list(dict.fromkeys(df["rule"]))
    # tab20 then tab20b: distinct colours for up to 40 rules (C0-C9 repeat after 10, and the training
    # and the detection jobs, the two longest kinds, came out in the same brown)
    palette = [colormaps["tab20"](i) for i in range(20)] + [colormaps["tab20b"](i) for i in range(20)]
    cmap = {r: palette[k % len(palette)] for k, r in enumerate(rules)}
    chain = set(blocking_chain(df)["job"]) if len(df) else set()
    fig = new_figure(10.0, 1.2 + 0.35 * max(n_lanes, 1) + 0.14 * math.ceil(len(rules) / 4))
    ax = fig.subplots()
    for r, ln in zip(df.itertuples(), lane):
        ax.barh(ln, (r.end - r.start) / 60.0, left=(r.start - t0) / 60.0, color=cmap[r.rule], height=0.8,
                edgecolor="black" if r.job in chain else "none", linewidth=1.2)
    for k, r in enumerate(rules):
        ax.barh(-10, 0, color=cmap[r], label=r)  # legend entries
    ax.set_ylim(-0.6, max(n_lanes, 1) - 0.4)
    ax.set_yticks(range(n_lanes), [f"lane {i + 1}" + (" (over cores)" if i >= cores else "")
                                   for i in range(n_lanes)])
    ax.set_xlabel("minutes since the first job started")
    ax.set_title(f"{title}: {len(df)} jobs; outlined: the blocking chain")
    ax.legend(fontsize=6, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.3),
              frameon=False)
    return write_figure(fig, out_png)
