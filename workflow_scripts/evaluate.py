"""Evaluate one method's detections on one dataset (nuScenes centre-distance AP); the metrics, the
per-class table and the PR curves are written together (all or none)."""

from common import job

import numpy as np

from sonardet.eval import evaluate_files
from sonardet.io.artifacts import read_json_file
from sonardet.io.atomic import atomic_outputs

with job(snakemake, "evaluate") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    ev = smk.params.evaluation
    metas = [read_json_file(p, "object metadata file") for p in smk.input.objects]
    symmetric = [m["cls"] for m in metas if m["rotationally_symmetric"]]
    periods = {m["cls"]: 2 * np.pi / m["symmetry_order"] for m in metas if m["symmetry_order"] > 1}
    with atomic_outputs([smk.output.metrics, smk.output.per_class, smk.output.pr]) as (metrics, per_class, pr):
        res = evaluate_files(
            smk.input.scenes, smk.input.detections, metrics, per_class, pr, smk.params.classes,
            ev["dist_thresholds_m"], ev["headline_m"], symmetric_classes=symmetric, min_recall=ev["min_recall"],
            min_precision=ev["min_precision"], dataset=smk.wildcards.dataset, yaw_periods_rad=periods,
            max_boxes_per_scene=ev["max_boxes_per_scene"],
        )
    log.info("%s on %s: mAP@%.1f m = %.4f", smk.wildcards.method, smk.wildcards.dataset, ev["headline_m"],
             res["mAP_headline"])
