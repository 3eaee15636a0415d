"""Implant simulated objects into a real survey line's seabed: the hybrid scenes (params `scenes`,
outputs in that order), the real survey read once."""

from common import job

import os

from sonardet.io.scenes import write_scene
from sonardet.objects import read_object
from sonardet.sim.hybrid import read_real_survey, simulate_hybrid_scene

with job(snakemake, "simulate_scenes_hybrid") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    cfg = smk.params.config
    objects = {os.path.basename(p)[: -len(".json")]: read_object(p) for p in smk.input.meta}
    survey = read_real_survey(smk.input.soundings, cfg["hybrid_test"]["crs"])
    log.info("%s: %d soundings, %d pings, transducer fit rms %.1f mm (median), origin %s", smk.input.soundings,
             len(survey.xyz), len(survey.pings), 1e3 * float(sorted(survey.fit_rms_m)[len(survey.pings) // 2]),
             survey.origin.tolist())
    ids = list(smk.params.scenes)
    for i, sid in enumerate(ids):
        scene = simulate_hybrid_scene(sid, cfg, objects, survey)
        write_scene(scene, smk.output.npz[i], smk.output.json[i])
        m = scene.meta
        log.info("%s (%d/%d): %d objects (%d visible), %d objects left out (off the covered seabed), %d soundings "
                 "moved onto objects, timings %s", sid, i + 1, len(ids), len(m["objects"]),
                 sum(o["visible"] for o in m["objects"]), m["hybrid"]["dropped_outside_coverage"],
                 m["hybrid"]["n_replaced"], {k: round(v, 2) for k, v in m["timings_s"].items()})
