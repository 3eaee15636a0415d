"""Run one per-scene method on every scene of a dataset in one job: the detector is built once and
the job's start-up paid once (benchmarks/job_startup.py). Writes each scene's detections and
statistics (all or none); the detector's build time is shared equally by the scenes' statistics."""

from common import job, job_method, job_resources

import json
from pathlib import Path

from sonardet import methods
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.io.scenes import read_scene_points

with job(snakemake, "detect_scenes") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    method = job_method(smk)
    scenes, det_paths, stats_paths = list(smk.input.scenes), list(smk.output.detections), list(smk.output.stats)
    if [Path(p).stem for p in scenes] != [Path(p).stem for p in det_paths]:
        raise RuntimeError(f"{method.name}: the job's scenes and detection files differ in order or ids")
    detector = methods.family(method.family).load(method, job_resources(smk, method))
    build_s = float(getattr(detector, "build_seconds", 0.0)) / max(len(scenes), 1)
    results = []
    for i, npz in enumerate(scenes, 1):
        scene = Path(npz).stem
        dets, stats = detector(read_scene_points(npz)["xyz"])
        stats["seconds"]["models"] = stats["seconds"].get("models", 0.0) + build_s
        stats["seconds"]["total"] += build_s
        results.append((scene, dets, stats))
        n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
        log.info("%s %s (%d/%d): %d detections (%d accepted), %.2f s", method.name, scene, i, len(scenes),
                 len(dets), n_acc, stats["seconds"]["total"])
    with atomic_outputs(det_paths + stats_paths) as staged:
        for (scene, dets, stats), det_path, stats_path in zip(results, staged[: len(results)],
                                                               staged[len(results):]):
            write_detections(det_path, scene, method.name, dets, smk.params.classes)
            atomic_write_text(stats_path, json.dumps({"scene": scene, **stats}, indent=1) + "\n")
