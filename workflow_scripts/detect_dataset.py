"""Run one method on every scene of a dataset in one job (its model loaded once); write the
detections and the job's timing (all or none)."""

from common import job, job_method, job_resources

import json
from pathlib import Path

from sonardet import methods
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text

with job(snakemake, "detect_dataset") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    method = job_method(smk)
    family = methods.family(method.family)
    dets, timing = family.detect_dataset(method, job_resources(smk, method), list(smk.input.scenes))
    outputs = list(smk.output.detections)
    missing = sorted({Path(p).stem for p in outputs} - set(dets))
    if missing:
        raise RuntimeError(f"{method.name} returned no result for scene(s) {missing}")
    with atomic_outputs(outputs + [smk.output.timing]) as staged:
        for path in staged[:-1]:
            write_detections(path, path.stem, method.name, dets[path.stem], smk.params.classes)
        atomic_write_text(staged[-1], json.dumps({"method": method.name, **timing}, indent=1) + "\n")
    log.info("%s: %d scenes, %d detections, %.2f s per scene", method.name, len(outputs),
             sum(len(d) for d in dets.values()), timing.get("s_per_scene") or 0.0)
