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
    params:
        manifest=report_manifest(),
    script:
        "../workflow_scripts/report.py"
