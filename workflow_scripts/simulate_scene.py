"""Synthesize scenes: seabed, rocks, settled objects, MBES survey, annotations.

The scenes of params `scenes`, outputs in that order: a few synthetic scenes per job, each also
writing its settled layout (output `settled`); or a whole scene set made under another config, whose
realism sets apply the synthetic scenes' settled layouts (input `settled`, same order) instead of
running the physics again (sonardet.sim.scene.apply_settled).
"""

from common import job

import json
import os

from sonardet.io.scenes import write_scene
from sonardet.objects import read_object
from sonardet.sim.scene import simulate_scene



def files(io, name: str) -> list[str]:
    """The files of a named input or output: one (a str) or several (a list); none when absent."""
    value = getattr(io, name, None) or []
    return [value] if isinstance(value, str) else list(value)


with job(snakemake, "simulate_scene") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    cfg = smk.params.config
    objects = {os.path.basename(p)[: -len(".json")]: read_object(p) for p in smk.input.meta}
    ids = list(smk.params.scenes)
    npz_out, json_out = files(smk.output, "npz"), files(smk.output, "json")
    settled_in, settled_out = files(smk.input, "settled"), files(smk.output, "settled")
    for i, sid in enumerate(ids):
        settled = None
        if settled_in:
            with open(settled_in[i]) as f:
                settled = json.load(f)
        scene = simulate_scene(sid, cfg, objects, settled=settled)
        write_scene(scene, npz_out[i], json_out[i])
        if settled_out:
            with open(settled_out[i], "w") as f:
                json.dump(scene.settled, f)
        m = scene.meta
        log.info("%s (%d/%d): %d objects (%d visible), %d removed, %d points (%.0f /m^2), %s lines, timings %s",
                 sid, i + 1, len(ids), len(m["objects"]), sum(o["visible"] for o in m["objects"]), len(m["removed"]),
                 m["stats"]["n_points"], m["stats"]["points_per_m2"], m["survey"]["direction"],
                 {k: round(v, 2) for k, v in m["timings_s"].items()})
