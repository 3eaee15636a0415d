# The report: tables (csv, Markdown, LaTeX), figures, results/README.md; `snakemake --report` renders
# the outputs flagged with report() into one self-contained HTML file.


rule report:
    input:
        dataset="results/tables/dataset_stats.csv",
        scenes=expand("results/scenes/{scene}.json", scene=SCENES),
        scene_benchmarks=expand(
            "results/benchmarks/simulate_scene/{scene}.tsv", scene=SCENES
        ),
        metrics=eval_files(),
        pr=expand("results/eval/{method}/synthetic/pr_curves.npz", method=METHODS),
        detections=[detection_files(m, "synthetic") for m in METHODS],
        stats=[
            expand(
                "results/stats/{method}/synthetic/{scene}.json",
                method=m,
                scene=DATASETS["synthetic"],
            )
            for m in METHODS
            if m.startswith("model_based_")
        ],
        inference=[
            f"results/stats/{m}/synthetic/inference.json"
            for m in METHODS
            if m.startswith("sasa_")
        ],
        training=[
            f"results/models/{m}/train.json" for m in METHODS if m.startswith("sasa_")
        ],
        losses=[
            f"results/models/{m}/loss.csv" for m in METHODS if m.startswith("sasa_")
        ],
        ablation=ablation_files(),
        noise=["results/noise/noise.json"] if NOISE else [],
        realism_ablation=(
            ["results/realism_ablation/summary.json"] if REALISM_EFFECTS else []
        ),
        hybrid_scenes=(
            dataset_scene_files("hybrid", "json")
            + dataset_scene_files("hybrid", "npz")
            if "hybrid" in DATASETS
            else []
        ),
        hybrid_detections=(
            [detection_files(m, "hybrid") for m in METHODS]
            if "hybrid" in DATASETS
            else []
        ),
        meta=object_files("json"),
        meshes=object_files("ply"),
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
    conda:
        "../environment.yml"
    threads: 1
    params:
        methods=METHODS,
        dr_pairs={m: m.replace("sasa_dr_", "sasa_") for m in DR_METHODS},
        datasets=EVAL_DATASETS,
        classes=CLASSES,
        test_scenes=DATASETS["synthetic"],
        train_scenes=SPLIT["train"],
        tables=REPORT_TABLES,
        figures=REPORT_FIGURES,
        config_info={
            "seed": config["seed"],
            "scenes": config["scenes"]["n_scenes"],
            "sasa preset": config["sasa"]["preset"],
        },
    script:
        "../workflow_scripts/report.py"
