"""Run a survey's method on one of its tiles; write its detections (survey coordinates) and statistics
(both or neither)."""

from common import job, job_method, job_resources

import json

from sonardet import methods
from sonardet.survey import read_tile_points
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text

with job(snakemake, "detect_survey_tile") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    survey, tile, method = smk.wildcards.survey, smk.wildcards.tile, job_method(smk)
    cloud = read_tile_points(smk.input.npz)
    log.info("%s %s: %d points (CRS %s)", survey, tile, len(cloud.xyz), cloud.crs)
    detector = methods.family(method.family).load(method, job_resources(smk, method))
    dets, stats = detector(cloud.xyz)
    with atomic_outputs([smk.output.detections, smk.output.stats]) as (det_path, stats_path):
        write_detections(det_path, tile, method.name, dets, smk.params.classes)
        atomic_write_text(stats_path, json.dumps({"survey": survey, "tile": tile, **stats}, indent=1) + "\n")
    n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
    log.info("%s %s (%s): %d detections (%d accepted), %.2f s", survey, tile, method.name, len(dets), n_acc,
             stats["seconds"]["total"])
