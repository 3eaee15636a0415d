# Synthetic scenes, the train/validation/test split and the dataset table.


# Scene simulation jobs of a few scenes each (common.smk: SCENE_JOBS): the training and dev scenes
# first, so the longest chain of the DAG (scenes -> training -> inference -> evaluation -> report)
# starts as early as it can; each scene's outputs are the same in any job.
for _job, (_priority, _ids) in SCENE_JOBS.items():

    rule:
        name:
            f"simulate_scene_{_job}"
        input:
            meshes=object_files("ply"),
            meta=object_files("json"),
        output:
            npz=expand("results/scenes/{scene}.npz", scene=_ids),
            json=expand("results/scenes/{scene}.json", scene=_ids),
            settled=expand("results/settled/{scene}.json", scene=_ids),
        log:
            f"results/logs/simulate_scene/{_job}.log",
        benchmark:
            f"results/benchmarks/simulate_scene/{_job}.tsv"
        priority: _priority
        conda:
            "../environment.yml"
        threads: 1
        resources:
            mem_mb=MEM_MB["simulate"],
            runtime=RUNTIME_MIN["simulate"] * len(_ids),
        params:
            config={
                k: config[k]
                for k in ("seed", "classes", "objects", "sensor", "scenes")
            },
            scenes=_ids,
        script:
            "../workflow_scripts/simulate_scene.py"


# One job per scene set made under another config (common.smk: SCENE_SETS): the realism sets reuse
# the synthetic scenes' settled layouts, the mismatch sets settle their own perturbed bodies. Scene
# jobs go before the detections that wait for them (common.smk: SCENE_PRIORITY_REST).
for _set, (_ids, _dir, _config, _reuse) in SCENE_SETS.items():

    rule:
        name:
            f"simulate_scenes_{_set}"
        input:
            meshes=object_files("ply"),
            meta=object_files("json"),
            settled=expand("results/settled/{scene}.json", scene=_ids) if _reuse else [],
        output:
            npz=expand(f"{_dir}/{{scene}}.npz", scene=_ids),
            json=expand(f"{_dir}/{{scene}}.json", scene=_ids),
        log:
            f"results/logs/simulate_scenes/{_set}.log",
        benchmark:
            f"results/benchmarks/simulate_scenes/{_set}.tsv"
        priority: SCENE_PRIORITY_REST
        conda:
            "../environment.yml"
        threads: 1
        resources:
            mem_mb=MEM_MB["simulate"],
            runtime=RUNTIME_MIN["simulate"] * len(_ids),
        params:
            config=_config,
            scenes=_ids,
        script:
            "../workflow_scripts/simulate_scene.py"


if HYBRID:

    rule simulate_scenes_hybrid:
        input:
            soundings=config["hybrid_test"]["soundings"],
            meshes=object_files("ply"),
            meta=object_files("json"),
        output:
            npz=expand("results/hybrid/scenes/{scene}.npz", scene=DATASETS["hybrid"]),
            json=expand("results/hybrid/scenes/{scene}.json", scene=DATASETS["hybrid"]),
        log:
            "results/logs/simulate_scenes/hybrid.log",
        benchmark:
            "results/benchmarks/simulate_scenes/hybrid.tsv"
        priority: SCENE_PRIORITY_REST
        conda:
            "../environment.yml"
        threads: 1
        resources:
            mem_mb=MEM_MB["simulate"],
            runtime=RUNTIME_MIN["simulate"] * len(DATASETS["hybrid"]),
        params:
            config={
                k: config[k]
                for k in (
                    "seed",
                    "classes",
                    "objects",
                    "sensor",
                    "scenes",
                    "hybrid_test",
                )
            },
            scenes=DATASETS["hybrid"],
        script:
            "../workflow_scripts/simulate_hybrid_scene.py"


rule split:
    output:
        expand("results/splits/{name}.txt", name=SPLITS),
    log:
        "results/logs/split.log",
    benchmark:
        "results/benchmarks/split.tsv"
    priority: PRIORITY["simulate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["simulate"],
        runtime=RUNTIME_MIN["simulate"],
    params:
        split=config["split"],
        n_scenes=config["scenes"]["n_scenes"],
        seed=config["seed"],
    script:
        "../workflow_scripts/split.py"


rule dataset_stats:
    input:
        scenes=scene_files("json"),
        splits=expand("results/splits/{name}.txt", name=SPLITS),
    output:
        "results/tables/dataset_stats.csv",
    log:
        "results/logs/dataset_stats.log",
    benchmark:
        "results/benchmarks/dataset_stats.tsv"
    priority: PRIORITY["evaluate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["evaluate"],
        runtime=RUNTIME_MIN["evaluate"],
    params:
        classes=CLASSES,
    script:
        "../workflow_scripts/dataset_stats.py"
