"""The time line of a finished workflow run, from its benchmark files (sonardet.report.timeline):
wall time, total job time, CPU time, idle core-time, the blocking chain (the jobs that set the end
time) and the seconds per rule; optionally a Gantt figure. Where the run finished (or failed) with
this DAG's Snakefile, also the Snakemake process's own CPU time against its jobs'
(``results/benchmarks/snakemake_process.json``, written by its onsuccess / onerror handlers), and
the job time per method (each job counted for the method it trains, runs, evaluates or ablates; the
scene simulations and the rest apart; ``sonardet.report.timeline.job_method``).

With ``--dag`` (run from the workflow folder with the run's config) it also asks Snakemake for the
job graph (a dry run with --forceall) and reports the dependency critical path: the chain of jobs,
each reading the one before's outputs, with the largest sum of measured seconds.

Usage: ``python benchmarks/workflow.py [--results results] [--cores 2] [--dag [--configfile c.yaml]]
[--png gantt.png] [--json out.json]``.
Meaningful for a fresh run (``rm -rf results .snakemake && snakemake --cores 2``): after a partial
rerun the old jobs keep their old times. The workflow's own rule ``run_timeline`` writes the same into
results/report/ at the end of every run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from sonardet.report.timeline import (  # noqa: E402
    critical_path,
    plot_gantt,
    read_benchmarks,
    read_process_usage,
    run_summary,
    summary_lines,
)


def job_graph(configfile: str | None) -> dict:
    """job (benchmark path under results/benchmarks, without .tsv) -> the jobs producing its inputs,
    from a Snakemake dry run of every job (--forceall)."""
    import re
    import subprocess

    cmd = [sys.executable, "-m", "snakemake", "-n", "--forceall", "--cores", "2"]
    if configfile:
        cmd += ["--configfile", configfile]
    text = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    jobs, cur = [], None
    for line in text.splitlines():
        if re.match(r"^(local)?(rule|checkpoint) \S+:$", line.strip()):
            cur = {"input": [], "output": [], "benchmark": None}
            jobs.append(cur)
        elif cur is not None and (m := re.match(r"^\s+(input|output|benchmark): (.*)$", line)):
            vals = [v.strip() for v in m.group(2).split(",")]
            if m.group(1) == "benchmark":
                cur["benchmark"] = vals[0].removeprefix("results/benchmarks/").removesuffix(".tsv")
            else:
                cur[m.group(1)] = vals
    producer = {o: j["benchmark"] for j in jobs if j["benchmark"] for o in j["output"]}
    return {j["benchmark"]: sorted({producer[i] for i in j["input"] if i in producer})
            for j in jobs if j["benchmark"]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", default="results")
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--dag", action="store_true", help="also the dependency critical path (runs snakemake -n)")
    ap.add_argument("--configfile", default=None)
    ap.add_argument("--png", default=None)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    # Every job of the finished run, its last one (run_timeline) included: it is part of the run's wall time.
    try:
        df = read_benchmarks(Path(args.results) / "benchmarks")
    except (FileNotFoundError, ValueError) as exc:
        print(f"workflow.py: {exc}", file=sys.stderr)
        return 2
    s = run_summary(df, args.cores)
    if not s["jobs"]:
        print(f"workflow.py: {Path(args.results) / 'benchmarks'} holds no benchmark file: no job of a run finished "
              "there yet", file=sys.stderr)
        return 1
    print("\n".join(summary_lines(s)[:-1]))  # its own chain lines follow
    proc = read_process_usage(Path(args.results) / "benchmarks")
    if proc is not None:
        s["snakemake_process"] = proc
        print(f"Snakemake process ({proc['outcome']}): own CPU {proc['own_cpu_s'] / 60:.1f} min over its "
              f"{proc['wall_s'] / 60:.1f} min ({100 * proc['own_core_share']:.0f} % of one core), its jobs' CPU "
              f"{proc['children_cpu_s'] / 60:.1f} min, peak RSS {proc['own_max_rss_mb']:.0f} MB")
    print(f"blocking chain ({s['chain_s'] / 60:.1f} min of jobs):")
    for c in s["chain"]:
        print(f"  {c['start_s'] / 60:6.1f} min  {c['seconds']:7.1f} s  {c['job']}")
    if args.dag:
        path, total = critical_path(df, job_graph(args.configfile))
        s["critical_path"], s["critical_path_s"] = path, total
        print(f"dependency critical path ({total / 60:.1f} min of jobs): {' -> '.join(path)}")
    print("seconds per rule (wall sum, jobs, longest job, CPU sum, CPU before the jobs' own work, Numba compilation):")
    for rule, v in s["per_rule"].items():
        print(f"  {rule:36s} {v['sum_s']:8.0f} s  {v['jobs']:4d}  {v['max_s']:7.1f} s  {v['cpu_s']:8.0f} s CPU"
              f"  {v['startup_cpu_s']:6.0f} s start-up  {v['jit_s']:5.0f} s compiling")
    print("seconds per method (sonardet.report.timeline.job_method: its trainings, detections, evaluations and "
          "ablation points; wall sum, jobs, CPU sum, methods):")
    for group, v in s["per_method"].items():
        print(f"  {group:36s} {v['sum_s']:8.0f} s  {v['jobs']:4d}  {v['cpu_s']:8.0f} s CPU  {', '.join(v['methods'])}")
    if args.png:
        plot_gantt(df, args.png, args.cores)
    if args.json:
        Path(args.json).write_text(json.dumps(s, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
