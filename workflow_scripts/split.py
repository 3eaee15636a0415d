"""Write the train/validation/test split and the nested training fractions (all files or none)."""

from common import job


from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.sim.dataset import make_splits, scene_ids

with job(snakemake, "split") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    sp = smk.params.split
    splits = make_splits(scene_ids(smk.params.n_scenes + sp["n_dev"]), sp["n_test"], sp["n_dev"], sp["fractions"],
                         smk.params.seed)
    with atomic_outputs(list(smk.output)) as staged:  # every split file or none
        for path in staged:
            atomic_write_text(path, "\n".join(splits[path.stem]) + "\n")
            log.info("%s: %d scenes", path.stem, len(splits[path.stem]))
