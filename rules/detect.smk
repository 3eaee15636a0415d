# Detection with every registered method (sonardet.methods): one job per dataset (per-scene methods,
# model-based: statistics per scene; per-dataset ones, SASA: a timing file; either way the detector is
# built or the model loaded once), and one training job per trained method.


# One rule per evaluation dataset for the per-scene methods too: a job runs the method on every scene
# of the dataset (the detector built once, the job's start-up paid once: benchmarks/job_startup.py)
# and writes each scene's detections and statistics. Methods that share a run on the dataset
# (SHARED_RUNS) have the rule after this one.
for _dataset in DATASETS:

    rule:
        name:
            f"detect_scenes_{_dataset}"
        input:
            unpack(dataset_detect_inputs(_dataset)),
        output:
            detections=[
                detection_file("{method}", _dataset, s) for s in DATASETS[_dataset]
            ],
            stats=[
                scene_stats_file("{method}", _dataset, s) for s in DATASETS[_dataset]
            ],
        log:
            f"results/logs/detect_scenes/{{method}}/{_dataset}.log",
        benchmark:
            f"results/benchmarks/detect_scenes/{{method}}/{_dataset}.tsv"
        wildcard_constraints:
            method=alone_re(_dataset, "per_scene"),
        priority: PRIORITY["detect"]
        conda:
            "../environment.yml"
        threads: lambda w: METHOD[w.method].threads
        resources:
            mem_mb=MEM_MB["detect"],
            runtime=RUNTIME_MIN["detect"],
        params:
            methods=lambda w: [METHOD[w.method].to_dict()],
            classes=CLASSES,
        script:
            "../workflow_scripts/detect_scenes.py"


# Per-scene methods that share their work on a dataset (sonardet.methods.shared_runs, e.g. the paper
# variant and the ladder's re-ranking of it): one job runs them together and writes every method's
# files, each the same detections as a job of that method alone.
for _dataset, _groups in SHARED_RUNS.items():
    for _k, _names in enumerate(_groups):

        rule:
            name:
                f"detect_scenes_{_dataset}_shared{_k}"
            input:
                **detect_inputs(_dataset, _names),
            output:
                detections=[
                    detection_file(m, _dataset, s)
                    for m in _names
                    for s in DATASETS[_dataset]
                ],
                stats=[
                    scene_stats_file(m, _dataset, s)
                    for m in _names
                    for s in DATASETS[_dataset]
                ],
            log:
                f"results/logs/detect_scenes/{'+'.join(_names)}/{_dataset}.log",
            benchmark:
                f"results/benchmarks/detect_scenes/{'+'.join(_names)}/{_dataset}.tsv"
            priority: PRIORITY["detect"]
            conda:
                "../environment.yml"
            threads: max(METHOD[m].threads for m in _names)
            resources:
                mem_mb=MEM_MB["detect"],
                runtime=RUNTIME_MIN["detect"],
            params:
                methods=[METHOD[m].to_dict() for m in _names],
                classes=CLASSES,
            script:
                "../workflow_scripts/detect_scenes.py"


# One rule per evaluation dataset: its outputs are every scene of the dataset.
for _dataset in DATASETS:

    rule:
        name:
            f"detect_dataset_{_dataset}"
        input:
            unpack(dataset_detect_inputs(_dataset)),
        output:
            detections=[
                detection_file("{method}", _dataset, s) for s in DATASETS[_dataset]
            ],
            timing=[dataset_timing_file("{method}", _dataset)],
        log:
            f"results/logs/detect_dataset/{{method}}/{_dataset}.log",
        benchmark:
            f"results/benchmarks/detect_dataset/{{method}}/{_dataset}.tsv"
        wildcard_constraints:
            method=alone_re(_dataset, "per_dataset"),
        priority: PRIORITY["detect"]
        conda:
            "../environment.yml"
        threads: lambda w: METHOD[w.method].threads
        resources:
            mem_mb=MEM_MB["detect"],
            runtime=RUNTIME_MIN["detect"],
        params:
            methods=lambda w: [METHOD[w.method].to_dict()],
            classes=CLASSES,
        script:
            "../workflow_scripts/detect_dataset.py"


# Per-dataset methods that share a job on a dataset (SHARED_DATASET_RUNS, e.g. every SASA model:
# each scene read and prepared once, the start-up paid once): each method's detections and timing
# file, each the same as a job of that method alone would write.
for _dataset, _groups in SHARED_DATASET_RUNS.items():
    for _k, _names in enumerate(_groups):

        rule:
            name:
                f"detect_dataset_{_dataset}_shared{_k}"
            input:
                **detect_inputs(_dataset, _names),
            output:
                detections=[
                    detection_file(m, _dataset, s)
                    for m in _names
                    for s in DATASETS[_dataset]
                ],
                timing=[dataset_timing_file(m, _dataset) for m in _names],
            log:
                f"results/logs/detect_dataset/{'+'.join(_names)}/{_dataset}.log",
            benchmark:
                f"results/benchmarks/detect_dataset/{'+'.join(_names)}/{_dataset}.tsv"
            priority: PRIORITY["detect"]
            conda:
                "../environment.yml"
            threads: max(METHOD[m].threads for m in _names)
            resources:
                mem_mb=MEM_MB["detect"],
                runtime=RUNTIME_MIN["detect"],
            params:
                methods=[METHOD[m].to_dict() for m in _names],
                classes=CLASSES,
            script:
                "../workflow_scripts/detect_dataset.py"


# One training rule per trained method, so that each gets its own priority (train_priority).
for _method in TRAINED:

    rule:
        name:
            f"train_{_method}"
        input:
            **train_inputs(_method),
        output:
            model=f"results/models/{_method}/model.pt",
            loss=f"results/models/{_method}/loss.csv",
            summary=f"results/models/{_method}/train.json",
        log:
            f"results/logs/train/{_method}.log",
        benchmark:
            f"results/benchmarks/train/{_method}.tsv"
        priority: train_priority(_method)
        conda:
            "../environment.yml"
        threads: METHOD[_method].threads
        resources:
            mem_mb=MEM_MB["train"],
            runtime=RUNTIME_MIN["train"],
        params:
            method=METHOD[_method].to_dict(),
        script:
            "../workflow_scripts/train.py"
