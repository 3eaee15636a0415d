"""Compile the package's Numba kernels into their on-disk cache: ``python -m sonardet.warm``.

``scripts/setup.sh`` runs it after installing, so that no job of the workflow compiles a kernel: the
first jobs of a run would otherwise compile them (about a minute of CPU on the 2-core machine, twice
over when two SASA trainings start together, each compiling the same kernels) and every later
process loads them from the cache (:mod:`sonardet.jit`). Numba keys its cache on each kernel's
argument types, so the kernels are compiled by running the real code paths once on tiny inputs, not
by calling them with guessed types:

* SASA: a tiny network trained for one epoch on two small synthetic scenes with validation on one
  (training and inference paths: sampling, ball query, batch norm, segment max, NMS), once with the
  fused kernels' serial row loops and once with their parallel ones (``PARALLEL_MIN_ELEMENTS`` 0);
* the model-based detector (``ours``: ground model, proposals, grid ICP, scoring) on a short survey
  line over one cone on a flat seabed, made with the project's sonar model.

What it prints: the compilations and their seconds (:func:`sonardet.jit.compile_stats`). A second
run compiles nothing (every kernel loads from the cache) and takes a few seconds. The results are
thrown away; nothing of a workflow run is read or written. It is a warm-up, not a test: the test
suite checks these code paths' results.
"""

from __future__ import annotations

import argparse
import json
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
_BOX_SIZES_M = {"reef_ring": (2.7, 2.7, 0.8), "reef_cone": (2.0, 2.0, 1.4), "tetrapod_b": (2.3, 2.5, 2.1),
                "tetrapod_s": (1.6, 1.7, 1.5)}


def _box_scene(folder: Path, seed: int) -> Path:
    """A 20 m x 20 m scene file (seabed at -11.5 m and 8 box-shaped elements, two of each class, with
    their labels) in the layout of the simulator's scenes; returns the ``.npz`` path."""
    rng = np.random.default_rng(seed)
    n_ground = 20_000
    pts = [np.c_[rng.uniform(0, 20, (n_ground, 2)), rng.normal(-11.5, 0.03, n_ground)]]
    labels, objs = [np.full(n_ground, -1)], []
    for i in range(8):
        cls = list(_BOX_SIZES_M)[i % 4]
        size = np.asarray(_BOX_SIZES_M[cls])
        centre = np.r_[2.5 + 4.5 * (i % 4) + rng.uniform(-0.5, 0.5), 5.0 + 10.0 * (i // 4), -11.5 + size[2] / 2]
        surface = rng.uniform(-0.5, 0.5, (600, 3)) * size
        surface[:, 2] = np.where(rng.random(600) < 0.4, size[2] / 2, surface[:, 2])
        pts.append(surface + centre)
        labels.append(np.full(600, i))
        box = [float(v) for v in centre] + [float(v) for v in size] + [0.0]
        objs.append({"id": i, "cls": cls, "pose": {"t": box[:3], "q": [1, 0, 0, 0]}, "box": box, "n_points": 600,
                     "visible": True})
    sid = f"warm{seed}"
    np.savez(folder / f"{sid}.npz", xyz=np.vstack(pts), label=np.concatenate(labels))
    (folder / f"{sid}.json").write_text(json.dumps({"schema_version": 1, "scene": sid, "seed": seed,
                                                    "config_hash": "warm", "extent": [0, 20, 0, 20], "objects": objs}))
    return folder / f"{sid}.npz"


def warm_sasa(folder: Path) -> None:
    """Train the tiny SASA network (one epoch, validation on one scene) with the fused kernels' serial
    and then their parallel row loops; outputs go to ``folder``."""
    from .detect.sasa import train
    from .detect.sasa.ops import kernels

    scenes = [_box_scene(folder, seed) for seed in (0, 1)]
    default_min = kernels.PARALLEL_MIN_ELEMENTS
    try:
        for k, min_elements in enumerate((default_min, 0)):
            kernels.PARALLEL_MIN_ELEMENTS = min_elements
            train(scenes, scenes[:1], _SASA_TINY, folder / f"sasa{k}", device="cpu", resume=False)
    finally:
        kernels.PARALLEL_MIN_ELEMENTS = default_min


def warm_model_based() -> None:
    """Run the ``ours`` detector on one survey line over a cone on a flat seabed (the default
    config's cone and sensor; templates of a few views)."""
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
    ModelBasedDetector(templates, {"reef_cone": cone}, variant="ours")(xyz)


def main(argv=None) -> int:
    """Warm the kernels (see the module docstring); prints what was compiled and how long it took."""
    ap = argparse.ArgumentParser(prog="python -m sonardet.warm", description=__doc__.splitlines()[0])
    ap.parse_args(argv)
    logging.disable(logging.WARNING)  # the tiny runs' own progress and warnings are of no interest here
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sonardet-warm-") as tmp:
        warm_sasa(Path(tmp))
    warm_model_based()
    c = compile_stats()
    print(f"sonardet.warm: {c['n']} Numba compilations in {c['s']:.0f} s "
          f"({time.perf_counter() - t:.0f} s in all; later processes load them from the cache)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
