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
    params:
        evaluation=config["evaluation"],
        classes=CLASSES,
    script:
        "../workflow_scripts/evaluate.py"
