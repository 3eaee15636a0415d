"""The main run's methods (default settings) evaluated on the ablation scenes."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

from sonardet.ablation import reference_point
from sonardet.io.atomic import atomic_write_text
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "ablation_reference") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    objects_dir = Path(smk.input.meta[0]).parent
    labels = list(smk.input.labels)
    rows = []
    for method in smk.params.methods:
        dets = [p for p in smk.input.detections if Path(p).parent.parent.name == method]
        fraction, train_s = None, None
        if method.startswith("model_based_"):
            stats = [json.loads(Path(p).read_text()) for p in smk.input.stats if Path(p).parent.parent.name == method]
            secs = [s["seconds"]["total"] for s in stats]
        else:
            inf = json.loads(next(Path(p) for p in smk.input.inference if Path(p).parent.parent.name == method)
                             .read_text())
            secs = [inf["s_per_scene"]]
            fraction = int(method.split("_")[-1])
            train_s = json.loads(next(Path(p) for p in smk.input.training if Path(p).parent.name == method)
                                 .read_text())["train_time_s"]
        rows.append(reference_point(f"{method} (default)", method.rsplit("_", 1)[0] if fraction else method, dets,
                                    labels, secs, smk.params.classes, smk.params.evaluation, objects_dir,
                                    fraction=fraction, train_time_s=train_s))
        log.info("%s: mAP@0.5 m %.4f on %d scenes, %.2f s per scene", method, rows[-1]["mAP"], len(dets),
                 rows[-1]["seconds_per_scene"])
    atomic_write_text(smk.output[0], json.dumps(rows, indent=1) + "\n")
