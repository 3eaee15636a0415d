"""The dataset table: scenes, objects and per-class counts and shares for train and test."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

from pathlib import Path

from sonardet.io.atomic import atomic_path
from sonardet.sim.dataset import dataset_stats, read_scene_meta, read_split
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "dataset_stats") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    metas = {Path(p).stem: read_scene_meta(p) for p in smk.input.scenes}
    splits = {Path(p).stem: read_split(p) for p in smk.input.splits}
    table = dataset_stats(metas, splits, smk.params.classes)
    with atomic_path(smk.output[0]) as tmp:
        table.to_csv(tmp, index=False)
    log.info("\n%s", table.to_string(index=False))
