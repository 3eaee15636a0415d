"""Run a trained SASA model on the scenes of one evaluation dataset."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

from sonardet.detect.sasa import infer
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_write_text
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "sasa_infer") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    cfg = smk.params.sasa
    method = smk.wildcards.model
    device = None if cfg["device"] == "auto" else cfg["device"]
    params = {"num_threads": int(smk.threads), "progress": False}
    for k in ("score_thresh", "nms_mode", "nms_iou", "nms_pre_max", "nms_post_max"):
        if k in cfg["params"]:
            params[k] = cfg["params"][k]
    dets, timing = infer(smk.input.model, smk.input.scenes, params=params, device=device)
    by_stem = {Path(p).stem: p for p in smk.output.detections}
    missing = sorted(set(by_stem) - set(dets))
    if missing:
        raise RuntimeError(f"SASA inference returned no result for scene(s) {missing}")
    for sid, path in by_stem.items():
        write_detections(path, sid, method, dets[sid], smk.params.classes)
    atomic_write_text(smk.output.timing, json.dumps({"method": method, **timing}, indent=1) + "\n")
    log.info("%s: %d scenes, %d detections, %.2f s per scene on %s", method, len(by_stem),
             sum(len(d) for d in dets.values()), timing.get("s_per_scene") or 0.0, timing.get("device"))
