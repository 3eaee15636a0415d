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
    priority: PRIORITY["ablation"]
    conda:
        "../environment.yml"
    threads: lambda w: ABLATION_METHOD[w.point].threads
    resources:
        mem_mb=MEM_MB["ablation"],
        runtime=RUNTIME_MIN["ablation"],
    params:
        point=lambda w: ABLATION[w.point],
        method=lambda w: ABLATION_METHOD[w.point].to_dict(),
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/ablation_point.py"


rule ablation_reference:
    input:
        files=[
            f
            for e in ablation_reference_methods()
            for f in e["detections"]
            + e["timing"]
            + ([e["train"]] if e["train"] else [])
        ],
        labels=expand("results/scenes/{scene}.json", scene=ABLATION_SCENES),
        meta=object_files("json"),
    output:
        "results/ablation/reference.json",
    log:
        "results/logs/ablation/reference.log",
    benchmark:
        "results/benchmarks/ablation/reference.tsv"
    priority: PRIORITY["ablation"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["evaluate"],
        runtime=RUNTIME_MIN["evaluate"],
    params:
        methods=ablation_reference_methods(),
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/ablation_reference.py"


# One-at-a-time realism ablation: the methods on the first test scenes with one realism effect on at a
# time, against the same scenes without (synthetic) and with every effect (realism).
rule realism_ablation:
    input:
        files=[
            f
            for e in realism_ablation_effects().values()
            for f in e["scenes"] + [p for ps in e["detections"].values() for p in ps]
        ],
        meta=object_files("json"),
    output:
        "results/realism_ablation/summary.json",
    log:
        "results/logs/realism_ablation.log",
    benchmark:
        "results/benchmarks/realism_ablation.tsv"
    priority: PRIORITY["evaluate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["evaluate"],
        runtime=RUNTIME_MIN["evaluate"],
    params:
        effects=realism_ablation_effects(),
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/realism_ablation.py"
