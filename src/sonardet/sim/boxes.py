"""Box scenes: scene files with the sizes of the simulator's scenes and none of its physics or sonar.

Where only the amount and layout of the data matter (the SASA speed benchmark, the Numba warm-up of
``python -m sonardet.warm``), a scene of random seabed soundings and box-shaped elements of the four
classes' sizes does, in a fraction of a second and without the object models. The files have the
layout of :func:`sonardet.io.scenes.write_scene` (``.npz`` with ``xyz`` and ``label``, ``.json`` with
the objects and their boxes), so every reader of scenes takes them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

#: Box sizes (l, w, h in m) of the default classes' elements.
BOX_SIZES_M = {"reef_ring": (2.7, 2.7, 0.8), "reef_cone": (2.0, 2.0, 1.4), "tetrapod_b": (2.3, 2.5, 2.1),
               "tetrapod_s": (1.6, 1.7, 1.5)}
SEABED_Z_M = -11.5


def write_box_scenes(out, n: int, extent_m: float = 40.0, points_per_m2: float = 180.0, n_objects: int = 55,
                     first_seed: int = 0) -> list[Path]:
    """Write n square scenes of side `extent_m` (m) into folder `out`, seeds first_seed, first_seed + 1, ...:
    a flat seabed at -11.5 m (N(0, 3 cm) noise) and `n_objects` boxes (the classes in turn, axis aligned,
    2 m clear of the edges, possibly overlapping), each surface sampled at `points_per_m2` (the top and
    four sides; the seabed too). Returns the ``.npz`` paths (scene ids ``syn000``, ``syn001``, ...
    after the seed)."""
    out = Path(out)
    paths = []
    for s in range(first_seed, first_seed + n):
        rng = np.random.default_rng(s)
        ng = int(round(points_per_m2 * extent_m * extent_m))
        pts = [np.c_[rng.uniform(0, extent_m, (ng, 2)), rng.normal(SEABED_Z_M, 0.03, ng)]]
        labels, objs = [np.full(ng, -1)], []
        for i in range(n_objects):
            cls = list(BOX_SIZES_M)[i % len(BOX_SIZES_M)]
            l, w, h = BOX_SIZES_M[cls]
            cx, cy = 2 + (extent_m - 4) * rng.random(2)
            k = int(points_per_m2 * (l * w + 2 * (l + w) * h))
            loc = rng.uniform(-0.5, 0.5, (k, 3)) * [l, w, h]
            face = rng.integers(0, 5, k)  # top, +x, -x, +y, -y
            loc[face == 0, 2] = h / 2
            loc[face == 1, 0] = l / 2
            loc[face == 2, 0] = -l / 2
            loc[face == 3, 1] = w / 2
            loc[face == 4, 1] = -w / 2
            pts.append(loc + [cx, cy, SEABED_Z_M + h / 2])
            labels.append(np.full(k, i))
            box = [float(cx), float(cy), SEABED_Z_M + h / 2, l, w, h, 0.0]
            objs.append({"id": i, "cls": cls, "pose": {"t": box[:3], "q": [1, 0, 0, 0]}, "box": box,
                         "n_points": k, "visible": True})
        sid = f"syn{s:03d}"
        np.savez(out / f"{sid}.npz", xyz=np.vstack(pts), label=np.concatenate(labels))
        (out / f"{sid}.json").write_text(json.dumps({"schema_version": 1, "scene": sid, "seed": s,
                                                     "config_hash": "boxes", "extent": [0, extent_m, 0, extent_m],
                                                     "objects": objs}))
        paths.append(out / f"{sid}.npz")
    return paths
