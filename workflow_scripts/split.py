"""Write the train/validation/test split and the nested training fractions."""

from common import job

from pathlib import Path

from sonardet.io.atomic import atomic_write_text
from sonardet.sim.dataset import make_splits, scene_ids

with job(snakemake, "split") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    sp = smk.params.split
    splits = make_splits(scene_ids(smk.params.n_scenes + sp["n_dev"]), sp["n_test"], sp["n_dev"], sp["fractions"],
                         smk.params.seed)
    for path in smk.output:
        name = Path(path).stem
        atomic_write_text(path, "\n".join(splits[name]) + "\n")
        log.info("%s: %d scenes", name, len(splits[name]))
