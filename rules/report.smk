# The report: tables (csv, Markdown, LaTeX), figures, results/README.md (sonardet.report.build); the
# outputs flagged with report() go into `snakemake --report`'s self-contained HTML file.


rule report:
    input:
        files=sorted(set(_manifest_files(report_manifest())) | set(scene_files("npz"))),
    output:
        tables=[
            report(
                f"results/report/tables/{t}.csv",
                caption=f"../config/report/table_{t}.rst",
                category="Tables",
            )
            for t in REPORT_TABLES
        ],
        tables_md=expand("results/report/tables/{t}.md", t=REPORT_TABLES),
        tables_tex=expand("results/report/tables/{t}.tex", t=REPORT_TABLES),
        figures=[
            report(
                f"results/report/figures/{f}.png",
                caption=f"../config/report/figure_{f}.rst",
                category="Figures",
            )
            for f in REPORT_FIGURES
        ],
        readme="results/README.md",
    log:
        "results/logs/report.log",
    benchmark:
        "results/benchmarks/report.tsv"
    priority: PRIORITY["report"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["report"],
        runtime=RUNTIME_MIN["report"],
    params:
        manifest=report_manifest(),
    script:
        "../workflow_scripts/report.py"


# The run's time line from every job's benchmark file (sonardet.report.timeline): wall time, job time,
# idle core-time, the chain of jobs that set the end time, a Gantt figure. It runs last.
rule run_timeline:
    input:
        # The report, the surveys and the evaluations of the default target (development sets too
        # with workflow.development_sets) come after every other job (it reads only benchmark files).
        report_files(),
        SURVEY_OUTPUTS,
        eval_files(DEFAULT_EVAL_DATASETS),
    output:
        summary="results/report/timeline.json",
        table="results/report/tables/timeline.csv",
        figure=report(
            "results/report/figures/timeline.png",
            caption="../config/report/figure_timeline.rst",
            category="Figures",
        ),
    log:
        "results/logs/run_timeline.log",
    benchmark:
        "results/benchmarks/run_timeline.tsv"
    priority: PRIORITY["report"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["report"],
        runtime=RUNTIME_MIN["report"],
    params:
        benchmarks="results/benchmarks",
        cores=workflow.cores,
    script:
        "../workflow_scripts/run_timeline.py"
