# Model-based (training-free) detection, one job per scene and variant.


rule detect_model_based:
    input:
        npz=lambda w: dataset_scene_file(w.dataset, w.scene, "npz"),
        meshes=object_files("ply"),
        meta=object_files("json"),
        templates=template_files(),
    output:
        detections="results/detections/model_based_{variant}/{dataset}/{scene}.json",
        stats="results/stats/model_based_{variant}/{dataset}/{scene}.json",
    log:
        "results/logs/detect_model_based/{variant}/{dataset}/{scene}.log",
    benchmark:
        "results/benchmarks/detect_model_based/{variant}/{dataset}/{scene}.tsv"
    conda:
        "../environment.yml"
    threads: 1
    params:
        detector=lambda w: config["model_based"][w.variant],
        classes=CLASSES,
    script:
        "../workflow_scripts/detect_model_based.py"
