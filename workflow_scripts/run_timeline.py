"""The run's time line from the benchmark files: summary JSON, per-rule table, Gantt figure."""

from common import job

import json

from sonardet.io.atomic import atomic_write_text
from sonardet.report.timeline import plot_gantt, read_benchmarks, run_summary

with job(snakemake, "run_timeline") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    df = read_benchmarks(smk.params.benchmarks)
    df = df[df["rule"] != "run_timeline"]  # this job's own file (from an earlier run)
    cores = int(smk.params.cores)
    summary = run_summary(df, cores)
    atomic_write_text(smk.output.summary, json.dumps(summary, indent=1) + "\n")
    atomic_write_text(smk.output.table, df.to_csv(index=False, lineterminator="\n"))
    plot_gantt(df, smk.output.figure, cores)
    log.info("%d jobs, wall %.0f s, job time %.0f s, idle core-time %.0f s (%.0f %% of %d cores held by jobs), "
             "CPU %.0f s (%d jobs' own exact records, the rest sampled); blocking chain %.0f s: %s", summary["jobs"],
             summary.get("wall_s", 0), summary.get("job_s", 0), summary.get("idle_core_s", 0),
             100 * summary.get("utilisation", 0), cores, summary.get("cpu_s", 0), summary.get("cpu_exact_jobs", 0),
             summary.get("chain_s", 0), " -> ".join(c["rule"] for c in summary.get("chain", [])))
