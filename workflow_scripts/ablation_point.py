"""Run one ablation grid point (a detector setting) on the ablation test scenes."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

from sonardet.ablation import run_point
from sonardet.io.atomic import atomic_write_text
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "ablation_point") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    point = smk.params.point
    if point["method"] == "sasa":
        from sonardet.detect.sasa.config import DEFAULTS, PAPER, resolve_params

        sasa = smk.params.base
        base = resolve_params(sasa["params"], PAPER if sasa["preset"] == "paper" else DEFAULTS)
    else:
        base = smk.params.base
    out = Path(smk.output[0])
    res = run_point(point, smk.input.scenes, smk.input.labels, base, smk.params.classes, smk.params.evaluation,
                    Path(smk.input.meta[0]).parent, Path(smk.input.templates[0]).parent,
                    out.parent / point["name"], train_npzs=getattr(smk.input, "train", None),
                    seed=smk.params.seed, threads=smk.threads)
    atomic_write_text(out, json.dumps(res, indent=1) + "\n")
    log.info("%s (%s): mAP@0.5 m %.4f, %.2f s per scene", point["name"], point["method"], res["mAP"],
             res["seconds_per_scene"])
