"""Train SASA on one training-data fraction (model, loss curve, summary)."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

from pathlib import Path

from sonardet.detect.sasa import ConfigMismatchError, train
from sonardet.detect.sasa.config import DEFAULTS, PAPER, resolve_params
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "sasa_train") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    cfg = smk.params.sasa
    params = resolve_params(
        {**cfg["params"], "seed": int(smk.params.seed), "classes": list(smk.params.classes),
         "num_threads": int(smk.threads)},
        PAPER if cfg["preset"] == "paper" else DEFAULTS,
    )
    # The training log is the rule's log; a progress bar in a log file is noise.
    params["progress"] = sys.stderr.isatty() and params["progress"]
    device = None if cfg["device"] == "auto" else cfg["device"]
    out_dir = Path(smk.output.model).parent
    log.info("training on %d scenes (fraction %s %%), %d validation scenes, %d epochs, batch %d, device %s",
             len(smk.input.train), smk.wildcards.fraction, len(smk.input.val), params["epochs"],
             params["batch_size"], cfg["device"])
    try:
        summary = train(smk.input.train, smk.input.val, params, out_dir, device=device, resume=True)
    except ConfigMismatchError as exc:
        # The workflow reruns this job because the config changed: the old checkpoint is stale.
        log.warning("%s; starting afresh", exc)
        summary = train(smk.input.train, smk.input.val, params, out_dir, device=device, resume=False)
    val = summary["val"]["mAP_headline"] if summary["val"] else float("nan")
    log.info("trained %d steps in %.0f s (%.2f s/step), peak RSS %s MB, mAP@0.5 m on the validation scenes %.3f "
             "(they are training scenes: a sanity check, not a result)", summary["steps"], summary["train_time_s"],
             summary["s_per_step"], summary.get("peak_rss_mb"), val)
