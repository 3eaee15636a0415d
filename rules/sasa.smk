# SASA: one training job per training-data fraction, one inference job per model and dataset.


rule sasa_train:
    input:
        train=lambda w: split_scene_files(f"train_{w.fraction}", "npz"),
        train_labels=lambda w: split_scene_files(f"train_{w.fraction}", "json"),
        val=split_scene_files("val", "npz"),
        val_labels=split_scene_files("val", "json"),
    output:
        model="results/models/sasa_{fraction}/model.pt",
        loss="results/models/sasa_{fraction}/loss.csv",
        summary="results/models/sasa_{fraction}/train.json",
    log:
        "results/logs/sasa_train/{fraction}.log",
    benchmark:
        "results/benchmarks/sasa_train/{fraction}.tsv"
    # The 100 % training is the DAG's longest job: start trainings as soon as their scenes exist.
    priority: 10
    conda:
        "../environment.yml"
    threads: config["sasa"]["threads"]
    resources:
        mem_mb=6000,
    params:
        sasa=config["sasa"],
        seed=config["seed"],
        classes=CLASSES,
    script:
        "../workflow_scripts/sasa_train.py"


# The same training with domain randomisation (config domain_randomisation): sasa_dr_{fraction}.
use rule sasa_train as sasa_train_dr with:
    output:
        model="results/models/sasa_dr_{fraction}/model.pt",
        loss="results/models/sasa_dr_{fraction}/loss.csv",
        summary="results/models/sasa_dr_{fraction}/train.json",
    log:
        "results/logs/sasa_train_dr/{fraction}.log",
    benchmark:
        "results/benchmarks/sasa_train_dr/{fraction}.tsv"
    params:
        # The configured SASA settings with the dr_* keys on top (sonardet.detect.sasa.config).
        sasa={
            **config["sasa"],
            "params": {
                **config["sasa"]["params"],
                **config["domain_randomisation"]["params"],
                "dr_enabled": True,
            },
        },
        seed=config["seed"],
        classes=CLASSES,


# One inference rule per evaluation dataset: a job loads the model once for all of the dataset's scenes.
for _dataset in DATASETS:

    rule:
        name:
            f"sasa_infer_{_dataset}"
        input:
            model="results/models/{model}/model.pt",
            scenes=dataset_scene_files(_dataset, "npz"),
        output:
            detections=expand(
                "results/detections/{{model}}/{dataset}/{scene}.json",
                dataset=_dataset,
                scene=DATASETS[_dataset],
            ),
            timing=f"results/stats/{{model}}/{_dataset}/inference.json",
        log:
            f"results/logs/sasa_infer/{{model}}/{_dataset}.log",
        benchmark:
            f"results/benchmarks/sasa_infer/{{model}}/{_dataset}.tsv"
        conda:
            "../environment.yml"
        threads: config["sasa"]["threads"]
        params:
            sasa=config["sasa"],
            classes=CLASSES,
        script:
            "../workflow_scripts/sasa_infer.py"
