"""Synthesize one scene: seabed, rocks, settled objects, MBES survey, annotations."""

from common import job

import os

from sonardet.io.scenes import write_scene
from sonardet.objects import read_object
from sonardet.sim.scene import simulate_scene

with job(snakemake, "simulate_scene") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    cfg = smk.params.config
    objects = {os.path.basename(p)[: -len(".json")]: read_object(p) for p in smk.input.meta}
    scene = simulate_scene(smk.wildcards.scene, cfg, objects)
    write_scene(scene, smk.output.npz, smk.output.json)
    m = scene.meta
    log.info("%s: %d objects (%d visible), %d removed, %d points (%.0f /m^2), %s lines, timings %s",
             smk.wildcards.scene, len(m["objects"]), sum(o["visible"] for o in m["objects"]), len(m["removed"]),
             m["stats"]["n_points"], m["stats"]["points_per_m2"], m["survey"]["direction"],
             {k: round(v, 2) for k, v in m["timings_s"].items()})
