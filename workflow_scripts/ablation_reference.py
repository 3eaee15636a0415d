"""The main run's methods (default settings) evaluated on the ablation scenes."""

from common import job

import json

from sonardet.experiments.ablation import reference_point
from sonardet.io.artifacts import read_json_file
from sonardet.io.atomic import atomic_write_text
from sonardet.methods import Method

with job(snakemake, "ablation_reference") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    rows = []
    for entry in smk.params.methods:
        method = Method.from_dict(entry["method"])
        timing = [read_json_file(p, "timing file") for p in entry["timing"]]
        secs = [t["seconds"]["total"] for t in timing] if method.runner == "per_scene" else [timing[0]["s_per_scene"]]
        train_s = read_json_file(entry["train"], "train.json")["train_time_s"] if entry.get("train") else None
        rows.append(reference_point(method, entry["detections"], list(smk.input.labels), secs, smk.params.classes,
                                    smk.params.evaluation, list(smk.input.meta), train_time_s=train_s))
        log.info("%s: mAP@0.5 m %.4f on %d scenes, %.2f s per scene", method.name, rows[-1]["mAP"],
                 len(entry["detections"]), rows[-1]["seconds_per_scene"])
    atomic_write_text(smk.output[0], json.dumps(rows, indent=1) + "\n")
