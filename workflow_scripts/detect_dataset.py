"""Run per-dataset methods on every scene of a dataset in one job (each model loaded once): usually
one method; several when they share a run (`sonardet.methods.shared_runs`, runner per_dataset: e.g.
every SASA model, each scene read and prepared once). Writes each method's detections and timing
file (all or none), each the same as a job of that method alone would write."""

from common import job, job_resources

import json
from pathlib import Path

from sonardet import methods
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text

with job(snakemake, "detect_dataset") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    run = [methods.Method.from_dict(d) for d in smk.params.methods]
    names = [m.name for m in run]
    scenes, det_paths, timing_paths = list(smk.input.scenes), list(smk.output.detections), list(smk.output.timing)
    n = len(scenes)
    if len(det_paths) != n * len(run) or len(timing_paths) != len(run):
        raise RuntimeError(f"{'+'.join(names)}: {len(det_paths)} detection and {len(timing_paths)} timing outputs "
                           f"for {n} scenes of {len(run)} method(s)")
    family = methods.family(run[0].family)
    results = family.detect_datasets(run, [job_resources(smk, m) for m in run], scenes)
    if len(run) > 1:
        log.info("one run for %s (each scene read and prepared once)", ", ".join(names))
    texts = []
    # The rule lists the detection outputs method by method, each in the order of the scenes.
    for k, (method, (dets, timing)) in enumerate(zip(run, results)):
        mine = det_paths[k * n:(k + 1) * n]
        missing = sorted({Path(p).stem for p in mine} - set(dets))
        if missing:
            raise RuntimeError(f"{method.name} returned no result for scene(s) {missing}")
        if len(run) > 1:
            timing = {**timing, "shared_run": names}
        texts.append(json.dumps({"method": method.name, **timing}, indent=1) + "\n")
        log.info("%s: %d scenes, %d detections, %.2f s per scene", method.name, n,
                 sum(len(d) for d in dets.values()), timing.get("s_per_scene") or 0.0)
    with atomic_outputs(det_paths + timing_paths) as staged:
        for k, (method, (dets, _)) in enumerate(zip(run, results)):
            for path in staged[k * n:(k + 1) * n]:
                write_detections(path, path.stem, method.name, dets[path.stem], smk.params.classes)
            atomic_write_text(staged[len(det_paths) + k], texts[k])
