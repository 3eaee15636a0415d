# Synthetic scenes, the train/validation/test split and the dataset table.


# One rule per priority class of scenes (common.smk: SCENE_PRIORITY): the smallest training fraction
# and the dev scenes first, so the longest chain of the DAG (scenes -> training -> inference ->
# evaluation -> report) starts as early as it can; the outputs are the same for every class.
for _klass, (_priority, _ids) in SCENE_PRIORITY.items():

    rule:
        name:
            f"simulate_scene_{_klass}"
        input:
            meshes=object_files("ply"),
            meta=object_files("json"),
        output:
            npz="results/scenes/{scene}.npz",
            json="results/scenes/{scene}.json",
        log:
            "results/logs/simulate_scene/{scene}.log",
        benchmark:
            "results/benchmarks/simulate_scene/{scene}.tsv"
        wildcard_constraints:
            scene=_alternation(_ids),
        priority: _priority
        conda:
            "../environment.yml"
        threads: 1
        resources:
            mem_mb=MEM_MB["simulate"],
            runtime=RUNTIME_MIN["simulate"],
        params:
            config={
                k: config[k]
                for k in ("seed", "classes", "objects", "sensor", "scenes")
            },
        script:
            "../workflow_scripts/simulate_scene.py"


rule simulate_scene_realism:
    input:
        meshes=object_files("ply"),
        meta=object_files("json"),
    output:
        npz="results/realism/scenes/{scene}.npz",
        json="results/realism/scenes/{scene}.json",
    log:
        "results/logs/simulate_scene_realism/{scene}.log",
    benchmark:
        "results/benchmarks/simulate_scene_realism/{scene}.tsv"
    priority: PRIORITY["simulate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["simulate"],
        runtime=RUNTIME_MIN["simulate"],
    params:
        config={
            k: v
            for k, v in realism_test_config(config).items()
            if k in ("seed", "classes", "objects", "sensor", "scenes")
        },
    script:
        "../workflow_scripts/simulate_scene.py"


rule simulate_scene_mismatch:
    input:
        meshes=object_files("ply"),
        meta=object_files("json"),
    output:
        npz="results/mismatch/scenes/{scene}.npz",
        json="results/mismatch/scenes/{scene}.json",
    log:
        "results/logs/simulate_scene_mismatch/{scene}.log",
    benchmark:
        "results/benchmarks/simulate_scene_mismatch/{scene}.tsv"
    priority: PRIORITY["simulate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["simulate"],
        runtime=RUNTIME_MIN["simulate"],
    params:
        config={
            k: v
            for k, v in mismatch_test_config(config).items()
            if k in ("seed", "classes", "objects", "sensor", "scenes")
        },
    script:
        "../workflow_scripts/simulate_scene.py"


rule simulate_scene_realism_effect:
    input:
        meshes=object_files("ply"),
        meta=object_files("json"),
    output:
        npz="results/realism_ablation/{effect}/scenes/{scene}.npz",
        json="results/realism_ablation/{effect}/scenes/{scene}.json",
    log:
        "results/logs/simulate_scene_realism_effect/{effect}/{scene}.log",
    benchmark:
        "results/benchmarks/simulate_scene_realism_effect/{effect}/{scene}.tsv"
    priority: PRIORITY["simulate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["simulate"],
        runtime=RUNTIME_MIN["simulate"],
    params:
        config=lambda w: {
            k: v
            for k, v in realism_effect_config(config, w.effect).items()
            if k in ("seed", "classes", "objects", "sensor", "scenes")
        },
    script:
        "../workflow_scripts/simulate_scene.py"


rule simulate_scene_hybrid:
    input:
        soundings=config["hybrid_test"]["soundings"],
        meshes=object_files("ply"),
        meta=object_files("json"),
    output:
        npz="results/hybrid/scenes/{scene}.npz",
        json="results/hybrid/scenes/{scene}.json",
    log:
        "results/logs/simulate_scene_hybrid/{scene}.log",
    benchmark:
        "results/benchmarks/simulate_scene_hybrid/{scene}.tsv"
    priority: PRIORITY["simulate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["simulate"],
        runtime=RUNTIME_MIN["simulate"],
    params:
        config={
            k: config[k]
            for k in ("seed", "classes", "objects", "sensor", "scenes", "hybrid_test")
        },
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
