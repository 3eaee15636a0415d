# Speed against error: one job per grid point, plus the default settings read from the main run.


rule ablation_point:
    input:
        unpack(ablation_point_inputs),
    output:
        "results/ablation/points/{point}.json",
    log:
        "results/logs/ablation/{point}.log",
    benchmark:
        "results/benchmarks/ablation/{point}.tsv"
    conda:
        "../environment.yml"
    threads: lambda w: config["sasa"]["threads"] if ABLATION[w.point]["method"] == "sasa" else 1
    params:
        point=lambda w: ABLATION[w.point],
        base=lambda w: ablation_base_params(ABLATION[w.point]),
        evaluation=config["evaluation"],
        classes=CLASSES,
        seed=config["seed"],
    script:
        "../workflow_scripts/ablation_point.py"


rule ablation_reference:
    input:
        detections=expand(
            "results/detections/{method}/synthetic/{scene}.json",
            method=METHODS,
            scene=ABLATION_SCENES,
        ),
        stats=expand(
            "results/stats/{method}/synthetic/{scene}.json",
            method=[m for m in METHODS if m.startswith("model_based_")],
            scene=ABLATION_SCENES,
        ),
        inference=expand(
            "results/stats/{method}/synthetic/inference.json",
            method=[m for m in METHODS if m.startswith("sasa_")],
        ),
        training=expand(
            "results/models/{method}/train.json",
            method=[m for m in METHODS if m.startswith("sasa_")],
        ),
        labels=expand("results/scenes/{scene}.json", scene=ABLATION_SCENES),
        meta=object_files("json"),
    output:
        "results/ablation/reference.json",
    log:
        "results/logs/ablation/reference.log",
    conda:
        "../environment.yml"
    threads: 1
    params:
        methods=METHODS,
        scenes=ABLATION_SCENES,
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/ablation_reference.py"


# One-at-a-time realism ablation: the methods on the first test scenes with one realism effect on at a
# time, against the same scenes without (synthetic) and with every effect (realism).
rule realism_ablation:
    input:
        detections=expand(
            "results/detections/{method}/{dataset}/{scene}.json",
            method=config["realism_ablation"]["methods"],
            dataset=REALISM_ABLATION_DATASETS,
            scene=REALISM_ABLATION_SCENES,
        ),
        labels=[
            dataset_scene_file(d, s, "json")
            for d in REALISM_ABLATION_DATASETS
            for s in REALISM_ABLATION_SCENES
        ],
        meta=object_files("json"),
    output:
        "results/realism_ablation/summary.json",
    log:
        "results/logs/realism_ablation.log",
    conda:
        "../environment.yml"
    threads: 1
    params:
        methods=config["realism_ablation"]["methods"],
        effects=REALISM_EFFECTS,
        effect_keys=REALISM_EFFECT_KEYS,
        scenes=REALISM_ABLATION_SCENES,
        dirs={d: DATASET_DIRS[d] for d in REALISM_ABLATION_DATASETS},
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/realism_ablation.py"
