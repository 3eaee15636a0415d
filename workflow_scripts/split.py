"""Write the train/validation/test split and the nested training fractions."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

from pathlib import Path

from sonardet.io.atomic import atomic_write_text
from sonardet.sim.dataset import make_splits, scene_ids
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "split") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    sp = smk.params.split
    splits = make_splits(scene_ids(smk.params.n_scenes), sp["n_test"], sp["n_val"], sp["fractions"], smk.params.seed)
    for path in smk.output:
        name = Path(path).stem
        atomic_write_text(path, "\n".join(splits[name]) + "\n")
        log.info("%s: %d scenes", name, len(splits[name]))
