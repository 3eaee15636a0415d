"""The run's time line from the benchmark files: summary JSON, per-rule table, Gantt figure."""

from common import job

import json

from sonardet.io.atomic import atomic_write_text
from sonardet.report.timeline import plot_gantt, read_benchmarks, run_summary, summary_lines

with job(snakemake, "run_timeline") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    df = read_benchmarks(smk.params.benchmarks)
    df = df[df["rule"] != "run_timeline"]  # this job's own file (from an earlier run)
    cores = int(smk.params.cores)
    summary = run_summary(df, cores)
    atomic_write_text(smk.output.summary, json.dumps(summary, indent=1) + "\n")
    atomic_write_text(smk.output.table, df.to_csv(index=False, lineterminator="\n"))
    plot_gantt(df, smk.output.figure, cores)
    for line in summary_lines(summary):
        log.info("%s", line)
