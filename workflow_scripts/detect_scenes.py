"""Run per-scene methods on every scene of a dataset in one job: the detector is built once and the
job's start-up paid once (benchmarks/job_startup.py). Usually one method; several when they share a
run (`sonardet.methods.shared_runs`: one detector does the work they have in common once, e.g. the
registrations of two rankings of `paper`). Writes each method's detections and statistics of each
scene (all or none); the detector's build time is shared equally by the scenes' statistics."""

from common import job, job_resources

import json
from pathlib import Path

from sonardet import methods
from sonardet.io.annotations import write_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.io.scenes import read_scene_points

with job(snakemake, "detect_scenes") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    run = [methods.Method.from_dict(d) for d in smk.params.methods]
    names = [m.name for m in run]
    scenes, det_paths, stats_paths = list(smk.input.scenes), list(smk.output.detections), list(smk.output.stats)
    n = len(scenes)
    if len(det_paths) != n * len(run) or len(stats_paths) != n * len(run):
        raise RuntimeError(f"{'+'.join(names)}: {len(det_paths)} detection and {len(stats_paths)} statistics "
                           f"outputs for {n} scenes of {len(run)} method(s)")
    # The rule lists the outputs method by method, each in the order of the scenes.
    for k, name in enumerate(names):
        if [Path(p).stem for p in scenes] != [Path(p).stem for p in det_paths[k * n:(k + 1) * n]]:
            raise RuntimeError(f"{name}: the job's scenes and detection files differ in order or ids")
    family = methods.family(run[0].family)
    resources = job_resources(smk, run[0])
    detector = family.load_shared(run, resources)
    if len(run) > 1:
        log.info("one run for %s (they share their work up to the ranking)", ", ".join(names))
    build_s = float(getattr(detector, "build_seconds", 0.0)) / max(n, 1)
    results = [[] for _ in run]
    for i, npz in enumerate(scenes, 1):
        scene = Path(npz).stem
        for k, (dets, stats) in enumerate(detector(read_scene_points(npz)["xyz"])):
            stats["seconds"]["models"] = stats["seconds"].get("models", 0.0) + build_s
            stats["seconds"]["total"] += build_s
            if len(run) > 1:
                stats["shared_run"] = names
            results[k].append((scene, dets, stats))
            n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
            log.info("%s %s (%d/%d): %d detections (%d accepted), %.2f s", names[k], scene, i, n, len(dets), n_acc,
                     stats["seconds"]["total"])
    flat = [r for per_method in results for r in per_method]
    with atomic_outputs(det_paths + stats_paths) as staged:
        for k, (scene, dets, stats) in enumerate(flat):
            write_detections(staged[k], scene, names[k // n], dets, smk.params.classes)
            atomic_write_text(staged[len(flat) + k], json.dumps({"scene": scene, **stats}, indent=1) + "\n")
