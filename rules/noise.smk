# Noise characterisation of a real survey and of the simulator's sensor (the source study's appendix).


rule noise_characterization:
    input:
        survey=config["noise"]["survey"],
    output:
        json="results/noise/noise.json",
        figure=report(
            "results/noise/noise.png",
            caption="../config/report/noise.rst",
            category="Sensor noise",
        ),
    log:
        "results/logs/noise_characterization.log",
    benchmark:
        "results/benchmarks/noise_characterization.tsv"
    priority: PRIORITY["evaluate"]
    conda:
        "../environment.yml"
    threads: 1
    resources:
        mem_mb=MEM_MB["evaluate"],
        runtime=RUNTIME_MIN["evaluate"],
    params:
        noise=config["noise"],
        sensor=config["sensor"],
        seed=config["seed"],
    script:
        "../workflow_scripts/noise_characterization.py"
