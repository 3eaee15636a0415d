"""Compile the package's Numba kernels into their on-disk cache: ``python -m sonardet.warm``.

``scripts/setup.sh`` runs it after installing, so that no job of the workflow compiles a kernel: the
first jobs of a run would otherwise compile them (about a minute of CPU on the 2-core machine, twice
over when two SASA trainings start together, each compiling the same kernels) and every later
process loads them from the cache (:mod:`sonardet.jit`). Numba keys its cache on each kernel's
argument types, so the kernels are compiled by running the real code paths once on tiny inputs, not
by calling them with guessed types:

* SASA: a tiny network trained for one epoch on two small box scenes (:mod:`sonardet.sim.boxes`) with
  validation on one
  (training and inference paths: sampling, ball query, batch norm, segment max, NMS), once with the
  fused kernels' serial row loops and once with their parallel ones (``PARALLEL_MIN_ELEMENTS`` 0)
  and domain randomisation (``dr_enabled``);
* the model-based detectors (``ours``: ground model, proposals, grid ICP, scoring; ``paper``: the
  windows' point-to-point ICP) on a short survey line over one cone on a flat seabed, made with the
  project's sonar model.

The two parts compile disjoint sets of kernels (no kernel of one is used by the other; each kernel
has its own cache index file), so with two or more cores they run side by side in two processes
(``--jobs``, default: the cores this process may use, at most 2): 92 s against 114-127 s one after
the other on an empty cache of the 2-core machine (docs/speed_log.md, "The warm-up's two parts").

What it prints: the compilations and their seconds (:func:`sonardet.jit.compile_stats`, summed over
the parts). A second run compiles nothing (every kernel loads from the cache) and takes a few
seconds. The results are thrown away; nothing of a workflow run is read or written. It is a
warm-up, not a test: the test suite checks these code paths' results.
"""

from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .jit import compile_stats

#: Tiny SASA settings (the smoke config's network): the kernels' argument types do not depend on sizes.
_SASA_TINY = {
    "epochs": 1, "batch_size": 2, "n_points": 512, "sa_npoints": [128, 64, 32],
    "sa_radii_m": [[0.4, 0.8], [0.8, 1.6], [1.6, 2.4]], "sa_nsamples": [[8, 8], [8, 8], [8, 8]],
    "sa_mlps": [[[8, 16], [8, 16]], [[16, 32], [16, 32]], [[32, 32], [32, 32]]],
    "sa_aggregation": [16, 32, 32], "sa_confidence_mlps": [[16], [16]], "vote_mlp": [16],
    "val_every_epochs": 1, "num_threads": 1, "progress": False,
}


def warm_sasa(folder: Path) -> None:
    """Train the tiny SASA network (one epoch, validation on one scene) with the fused kernels' serial
    and then their parallel row loops; outputs go to ``folder``."""
    from .detect.sasa import train
    from .detect.sasa.ops import kernels
    from .sim.boxes import write_box_scenes

    scenes = write_box_scenes(folder, 2, extent_m=20.0, points_per_m2=50.0, n_objects=8)
    default_min = kernels.PARALLEL_MIN_ELEMENTS
    try:
        for k, min_elements in enumerate((default_min, 0)):
            kernels.PARALLEL_MIN_ELEMENTS = min_elements
            # the second one with domain randomisation (its compiled helpers in sasa.data)
            train(scenes, scenes[:1], dict(_SASA_TINY, dr_enabled=k == 1), folder / f"sasa{k}", device="cpu",
                  resume=False)
    finally:
        kernels.PARALLEL_MIN_ELEMENTS = default_min


def warm_model_based() -> None:
    """Run the ``ours`` and ``paper`` detectors on one survey line over a cone on a flat seabed (the
    default config's cone and sensor; templates of a few views)."""
    from .config import validate_config
    from .detect.model_based import ModelBasedDetector
    from .objects import build_object, object_info
    from .sim.mbes import RaycastTarget, SensorConfig, scan, straight_line
    from .sim.templates import scan_templates

    cfg = validate_config({})
    sensor = SensorConfig.from_dict(cfg["sensor"])
    cone = object_info(build_object("reef_cone", cfg["objects"]), cfg["objects"]["density_kg_m3"])
    views = {"yaw_deg": [0], "directions": ["x", "y"], "offsets_m": [-5.0, 0.0, 5.0], "altitude_m": 11.5}
    templates = {"reef_cone": scan_templates("reef_cone", cone.mesh.vertices, cone.mesh.faces, cone.symmetry_order,
                                             views, sensor, np.random.default_rng(0))}
    vertices = np.asarray(cone.mesh.vertices)
    seabed = (np.array([[-2.0, -2.0, -11.5], [12.0, -2.0, -11.5], [12.0, 12.0, -11.5], [-2.0, 12.0, -11.5]]),
              np.array([[0, 1, 2], [0, 2, 3]]))
    placed = (vertices + [5.0, 5.0, -11.5 - vertices[:, 2].min()], np.asarray(cone.mesh.faces))
    line = straight_line((-1.0, 9.0), (11.0, 9.0), 0.0, sensor, 11.5)
    xyz = scan(RaycastTarget([seabed, placed]), line, sensor, np.random.default_rng(0)).xyz
    for variant in ("ours", "paper"):
        ModelBasedDetector(templates, {"reef_cone": cone}, variant=variant)(xyz)


def _warm_part(part: str) -> dict:
    """Run one part of the warm-up in this process ("sasa" or "model_based"); its compile stats."""
    logging.disable(logging.WARNING)  # the tiny runs' own progress and warnings are of no interest here
    if part == "sasa":
        with tempfile.TemporaryDirectory(prefix="sonardet-warm-") as tmp:
            warm_sasa(Path(tmp))
    else:
        warm_model_based()
    return compile_stats()


_PARTS = ("sasa", "model_based")


def main(argv=None) -> int:
    """Warm the kernels (see the module docstring); prints what was compiled and how long it took."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from .survey.tiling import available_cores

    ap = argparse.ArgumentParser(prog="python -m sonardet.warm", description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=None,
                    help="parts compiled at once in their own processes (default: the usable cores, at most 2; "
                         "1: both in this process, one after the other)")
    args = ap.parse_args(argv)
    jobs = min(len(_PARTS), available_cores()) if args.jobs is None else args.jobs
    if jobs < 1:
        ap.error(f"--jobs {jobs}: at least 1")
    t = time.perf_counter()
    if jobs == 1:
        for part in _PARTS:
            last = _warm_part(part)
        stats = [last]  # one process: its counts after the last part hold both
    else:
        # spawn: fresh interpreters (no inherited Numba or OpenMP thread state), the environment passed on
        with ProcessPoolExecutor(max_workers=min(jobs, len(_PARTS)), mp_context=get_context("spawn")) as ex:
            stats = list(ex.map(_warm_part, _PARTS))
    n, secs = sum(c["n"] for c in stats), sum(c["s"] for c in stats)
    print(f"sonardet.warm: {n} Numba compilations in {secs:.0f} s "
          f"({time.perf_counter() - t:.0f} s in all; later processes load them from the cache)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
