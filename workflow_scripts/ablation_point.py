"""Run one ablation grid point (a detector setting) on the ablation test scenes."""

from common import job, job_method, job_resources

import json
from pathlib import Path

from sonardet.experiments.ablation import run_point
from sonardet.io.atomic import atomic_write_text

with job(snakemake, "ablation_point") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    point, method = smk.params.point, job_method(smk)
    out = Path(smk.output[0])
    res = run_point(point, method, list(smk.input.scenes), list(smk.input.labels), smk.params.classes,
                    smk.params.evaluation, list(smk.input.meta), job_resources(smk, method),
                    out.parent / point["name"], train_npzs=list(getattr(smk.input, "train", [])))
    atomic_write_text(out, json.dumps(res, indent=1) + "\n")
    log.info("%s (%s): mAP@0.5 m %.4f, %.2f s per scene", point["name"], point["method"], res["mAP"],
             res["seconds_per_scene"])
