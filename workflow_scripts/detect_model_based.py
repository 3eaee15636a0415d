"""Run one variant of the model-based detector on one scene; write its detections and statistics."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

from sonardet.detect.model_based import detect
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_write_text
from sonardet.io.scenes import read_scene_points
from sonardet.io.templates import read_templates
from sonardet.objects import read_object
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "detect_model_based") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    variant, scene = smk.wildcards.variant, smk.wildcards.scene
    objects = {Path(p).stem: read_object(p) for p in smk.input.meta}
    templates = {Path(p).stem: read_templates(p) for p in smk.input.templates}
    xyz = read_scene_points(smk.input.npz)["xyz"]
    dets, stats = detect(xyz, templates, objects, smk.params.detector, variant)
    write_detections(smk.output.detections, scene, f"model_based_{variant}", dets, smk.params.classes)
    atomic_write_text(smk.output.stats, json.dumps({"scene": scene, **stats}, indent=1) + "\n")
    log.info("%s %s: %d detections (%d accepted), %d windows/proposals (%d skipped), %d ICP runs, %.2f s",
             variant, scene, len(dets), sum(d["extras"]["accepted"] for d in dets), stats["windows"],
             stats["windows_skipped"], stats["icp_runs"], stats["seconds"]["total"])
