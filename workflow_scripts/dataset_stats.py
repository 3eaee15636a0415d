"""The dataset table: scenes, objects and per-class counts and shares for train and test."""

from common import job

from pathlib import Path

from sonardet.io.atomic import atomic_path
from sonardet.sim.dataset import dataset_stats, read_scene_meta, read_split

with job(snakemake, "dataset_stats") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    metas = {Path(p).stem: read_scene_meta(p) for p in smk.input.scenes}
    splits = {Path(p).stem: read_split(p) for p in smk.input.splits}
    table = dataset_stats(metas, splits, smk.params.classes)
    with atomic_path(smk.output[0]) as tmp:
        table.to_csv(tmp, index=False)
    log.info("\n%s", table.to_string(index=False))
