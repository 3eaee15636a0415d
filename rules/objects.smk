# Object meshes of each class and their template scans.


rule object_mesh:
    output:
        ply="results/objects/{cls}.ply",
        json="results/objects/{cls}.json",
    log:
        "results/logs/object_mesh/{cls}.log",
    benchmark:
        "results/benchmarks/object_mesh/{cls}.tsv"
    priority: PRIORITY["objects"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["objects"],
        runtime=RUNTIME_MIN["objects"],
    params:
        objects=config["objects"],
    script:
        "../workflow_scripts/object_mesh.py"


rule template_scan:
    input:
        ply="results/objects/{cls}.ply",
        json="results/objects/{cls}.json",
    output:
        "results/templates/{cls}.npz",
    log:
        "results/logs/template_scan/{cls}.log",
    benchmark:
        "results/benchmarks/template_scan/{cls}.tsv"
    priority: PRIORITY["objects"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["objects"],
        runtime=RUNTIME_MIN["objects"],
    params:
        sensor=config["sensor"],
        templates=config["templates"],
        seed=config["seed"],
    script:
        "../workflow_scripts/template_scan.py"
