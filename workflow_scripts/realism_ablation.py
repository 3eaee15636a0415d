"""One-at-a-time realism ablation: mAP of each method with one realism effect on at a time."""

from common import job

import json

from sonardet.experiments.ablation import realism_effect_rows
from sonardet.io.atomic import atomic_write_text

with job(snakemake, "realism_ablation") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    rows = realism_effect_rows(dict(smk.params.effects), list(smk.params.classes), smk.params.evaluation,
                               list(smk.input.meta))
    atomic_write_text(smk.output[0], json.dumps(rows, indent=1) + "\n")
    for r in sorted(rows, key=lambda r: (r["method"], r["delta_mAP"])):
        log.info("%-18s %-16s mAP %.3f (%+.3f)", r["method"], r["effect"], r["mAP"], r["delta_mAP"])
