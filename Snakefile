# sonardet: training-free and learned 3D detection of reef structures in multibeam sonar point clouds.
# Run: snakemake --cores 2 (default config) or --configfile tests/config/smoke.yaml (tiny).
from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


include: "rules/common.smk"
include: "rules/objects.smk"
include: "rules/scenes.smk"
include: "rules/detect.smk"
include: "rules/evaluate.smk"
include: "rules/ablation.smk"
include: "rules/noise.smk"
include: "rules/survey.smk"
include: "rules/report.smk"


rule all:
    default_target: True
    input:
        final_outputs(),
        SURVEY_OUTPUTS,
        "results/report/timeline.json",


# Every method on the development sets (dev, realism_dev, mismatch_dev), evaluated and compared: what
# a choice of a threshold or setting reads. Not in the default target unless
# workflow.development_sets is true (the report reads none of it): `snakemake --cores 2 development`.
rule development:
    input:
        eval_files(DEV_DATASETS),


onstart:
    lift_local_job_rate_limit()


# The Snakemake process's own CPU time (scheduling, input functions, file checks) beside its jobs':
# results/benchmarks/snakemake_process.json, read by benchmarks/workflow.py.
onsuccess:
    record_process_usage("success")


onerror:
    record_process_usage("error")
