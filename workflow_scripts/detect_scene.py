"""Run one method on one scene; write its detections and the job's statistics (both or neither)."""

from common import job, job_method, job_resources

import json

from sonardet import methods
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.io.scenes import read_scene_points

with job(snakemake, "detect_scene") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    method, scene = job_method(smk), smk.wildcards.scene
    detector = methods.family(method.family).load(method, job_resources(smk, method))
    dets, stats = detector(read_scene_points(smk.input.npz)["xyz"])
    # A job detects one scene: what the detector built before it ran (class models) is part of its cost.
    build_s = float(getattr(detector, "build_seconds", 0.0))
    stats["seconds"]["models"] = stats["seconds"].get("models", 0.0) + build_s
    stats["seconds"]["total"] += build_s
    with atomic_outputs([smk.output.detections, smk.output.stats]) as (det_path, stats_path):
        write_detections(det_path, scene, method.name, dets, smk.params.classes)
        atomic_write_text(stats_path, json.dumps({"scene": scene, **stats}, indent=1) + "\n")
    n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
    log.info("%s %s: %d detections (%d accepted), %.2f s", method.name, scene, len(dets), n_acc,
             stats["seconds"]["total"])
