"""Run the model-based detector on one tile of a survey; write its detections (survey coordinates) and
statistics."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

from sonardet.detect.model_based import detect
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_write_text
from sonardet.io.templates import read_templates
from sonardet.objects import read_object
from sonardet.survey import read_tile_points
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "detect_survey_tile") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    survey, tile, variant = smk.wildcards.survey, smk.wildcards.tile, smk.params.variant
    objects = {Path(p).stem: read_object(p) for p in smk.input.meta}
    templates = {Path(p).stem: read_templates(p) for p in smk.input.templates}
    cloud = read_tile_points(smk.input.npz)
    log.info("%s %s: %d points (CRS %s)", survey, tile, len(cloud.xyz), cloud.crs)
    dets, stats = detect(cloud.xyz, templates, objects, smk.params.detector, variant)
    write_detections(smk.output.detections, tile, f"model_based_{variant}", dets, smk.params.classes)
    atomic_write_text(smk.output.stats, json.dumps({"survey": survey, "tile": tile, **stats}, indent=1) + "\n")
    log.info("%s %s (%s): %d detections (%d accepted), %d proposals (%d skipped), %d ICP runs, %.2f s", survey,
             tile, variant, len(dets), sum(d["extras"]["accepted"] for d in dets), stats["windows"],
             stats["windows_skipped"], stats["icp_runs"], stats["seconds"]["total"])
