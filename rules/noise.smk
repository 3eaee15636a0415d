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
    conda:
        "../environment.yml"
    threads: 1
    params:
        noise=config["noise"],
        sensor=config["sensor"],
        seed=config["seed"],
    script:
        "../workflow_scripts/noise_characterization.py"
