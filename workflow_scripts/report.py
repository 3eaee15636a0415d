"""Write the report: tables (csv, md, tex), figures and results/README.md from this run's results."""

from common import job

from pathlib import Path

from sonardet.report.build import write_report

with job(snakemake, "report") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    tables, figures = write_report(smk.params.manifest, Path(smk.output.tables_md[0]).parent,
                                   Path(smk.output.figures[0]).parent, smk.output.readme)
    log.info("report: %d tables, %d figures, summary %s", len(tables), len(figures), smk.output.readme)
