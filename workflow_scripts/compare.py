"""All methods on one dataset: mAP with paired bootstrap intervals, differences to the reference
method, and the accepted-only and don't-care scorings."""

from common import job

import json

from sonardet.eval.compare import compare_files
from sonardet.io.atomic import atomic_write_text

with job(snakemake, "compare") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    ev = smk.params.evaluation
    detections = dict(smk.params.detections)
    reference = ev["reference"] if ev["reference"] in detections else None
    out = compare_files(list(smk.input.scenes), detections, list(smk.input.meta), smk.params.classes, ev, reference,
                        ev["dont_care"], ev["bootstrap"]["n_resamples"], smk.params.seed, ev["bootstrap"]["level"])
    out["dataset"] = smk.wildcards.dataset
    atomic_write_text(smk.output[0], json.dumps(out, indent=1, allow_nan=False) + "\n")
    for name, rows in out["scorings"].items():
        for m, r in rows.items():
            log.info("%-10s %-22s mAP %.3f [%.3f, %.3f]%s", name, m, r["mAP"], r["low"], r["high"],
                     f", {r['diff']['mAP']:+.3f} [{r['diff']['low']:+.3f}, {r['diff']['high']:+.3f}] vs "
                     f"{r['diff']['vs']}" if "diff" in r else "")
