# nuScenes-style evaluation of each method's detections on each dataset.


rule evaluate:
    input:
        scenes=lambda w: dataset_scene_files(w.dataset, "json"),
        objects=object_files("json"),
        detections=lambda w: detection_files(w.method, w.dataset),
    output:
        metrics="results/eval/{method}/{dataset}/metrics.json",
        per_class="results/eval/{method}/{dataset}/per_class.csv",
        pr="results/eval/{method}/{dataset}/pr_curves.npz",
    log:
        "results/logs/evaluate/{method}/{dataset}.log",
    benchmark:
        "results/benchmarks/evaluate/{method}/{dataset}.tsv"
    priority: PRIORITY["evaluate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["evaluate"],
        runtime=RUNTIME_MIN["evaluate"],
    params:
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/evaluate.py"


# All methods on one dataset: mAP with paired bootstrap intervals, differences to the reference method
# and the accepted-only and don't-care scorings (sonardet.eval.compare).
rule compare:
    input:
        scenes=lambda w: dataset_scene_files(w.dataset, "json"),
        detections=lambda w: [
            f for m in methods_on(w.dataset) for f in detection_files(m, w.dataset)
        ],
        meta=object_files("json"),
    output:
        "results/eval/compare/{dataset}.json",
    log:
        "results/logs/compare/{dataset}.log",
    benchmark:
        "results/benchmarks/compare/{dataset}.tsv"
    priority: PRIORITY["evaluate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["evaluate"],
        runtime=RUNTIME_MIN["evaluate"],
    params:
        detections=lambda w: {
            m: detection_files(m, w.dataset) for m in methods_on(w.dataset)
        },
        evaluation=config["evaluation"],
        classes=CLASSES,
        seed=lambda w: derive_seed(config["seed"], "bootstrap", w.dataset),
    script:
        "../workflow_scripts/compare.py"
