"""Train one method on its training fraction (model, loss curve, summary)."""

from common import job, job_method, job_resources

from pathlib import Path

from sonardet import methods

with job(snakemake, "train") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    method = job_method(smk)
    summary = methods.family(method.family).train(method, list(smk.input.train), list(smk.input.val),
                                                  Path(smk.output.model).parent, job_resources(smk, method))
    val = (summary.get("val") or {}).get("mAP_headline", float("nan"))
    log.info("%s: %d steps in %.0f s (%.2f s/step), peak RSS %s MB, mAP@0.5 m on the validation scenes %.3f "
             "(they are training scenes: a sanity check, not a result)", method.name, summary["steps"],
             summary["train_time_s"], summary["s_per_step"], summary.get("peak_rss_mb"), val)
