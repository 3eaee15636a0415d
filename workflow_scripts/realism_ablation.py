"""One-at-a-time realism ablation: mAP of each method with one realism effect on at a time."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

from sonardet.ablation import realism_effect_rows
from sonardet.io.atomic import atomic_write_text
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "realism_ablation") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    dirs = smk.params.dirs
    datasets = {"none": ("synthetic", dirs["synthetic"]), "all": ("realism", dirs["realism"])}
    datasets.update({e: (d, dirs[d]) for e, d in smk.params.effects.items()})
    root = Path(smk.input.detections[0]).parents[2]
    rows = realism_effect_rows(list(smk.params.methods), datasets, list(smk.params.scenes),
                               list(smk.params.classes), smk.params.evaluation, Path(smk.input.meta[0]).parent,
                               detections_root=root)
    keys = dict(smk.params.effect_keys)
    for r in rows:
        r["keys"] = keys.get(r["effect"], [])
    atomic_write_text(smk.output[0], json.dumps(rows, indent=1) + "\n")
    for r in sorted(rows, key=lambda r: (r["method"], r["delta_mAP"])):
        log.info("%-18s %-16s mAP %.3f (%+.3f)", r["method"], r["effect"], r["mAP"], r["delta_mAP"])
