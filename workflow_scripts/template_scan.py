"""Scan one class's mesh with the MBES sensor model from several views and save the templates."""

from common import job

import numpy as np

from sonardet.io.templates import write_templates
from sonardet.objects import read_object
from sonardet.seeds import derive_seed
from sonardet.sim.mbes import SensorConfig
from sonardet.sim.templates import scan_templates

with job(snakemake, "template_scan") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    obj = read_object(smk.input.json, smk.input.ply)
    rng = np.random.default_rng(derive_seed(smk.params.seed, "template", obj.cls))
    tv = scan_templates(obj.cls, obj.mesh.vertices, obj.mesh.faces, obj.symmetry_order, smk.params.templates,
                        SensorConfig.from_dict(smk.params.sensor), rng)
    write_templates(smk.output[0], tv)
    log.info("%s: %d views, %d points", obj.cls, tv.n_views, len(tv.xyz))
