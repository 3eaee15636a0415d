"""A toy detection method, defined only here and registered from the test config (key `plugins`),
to show that a new detector needs no edit outside its own module and the config.

`centroid`: the soundings higher than `min_height_m` above a coarse seabed (the lowest sounding of
each `cell_m` cell) form one object of class `cls`, boxed by their extent, at their centroid.
Config:

    plugins: [tests/plugins/centroid_method.py]
    methods:
      centroid: {min_height_m: 0.3, cell_m: 2.0, cls: reef_cone}
"""

from __future__ import annotations

import time

import numpy as np

from sonardet import methods
from sonardet.methods import Method, MethodFamily

DEFAULTS = {"min_height_m": 0.3, "cell_m": 2.0, "cls": None}


def centroid_box(xyz: np.ndarray, min_height_m: float, cell_m: float) -> list[float] | None:
    """[x, y, z, l, w, h, yaw] of the soundings above the seabed, or None when there are none."""
    ij = np.floor((xyz[:, :2] - xyz[:, :2].min(0)) / cell_m).astype(np.int64)
    key = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    floor = np.full(int(key.max()) + 1, np.inf)
    np.minimum.at(floor, key, xyz[:, 2])
    above = xyz[xyz[:, 2] - floor[key] > min_height_m]
    if len(above) < 3:
        return None
    lo, hi = above.min(0), above.max(0)
    c = above.mean(0)
    return [float(c[0]), float(c[1]), float(0.5 * (lo[2] + hi[2])), *(float(v) for v in hi - lo), 0.0]


class Centroid(MethodFamily):
    """One box around everything above the seabed."""

    name = "centroid"
    label = "toy"
    prefix = "centroid"

    def methods(self, config: dict) -> list[Method]:
        settings = (config.get("methods") or {}).get(self.name)
        if settings is None:
            return []
        s = {**DEFAULTS, **settings}
        s["cls"] = s["cls"] or config["classes"][0]
        return [Method(name="centroid", family=self.name, settings=s, resources=())]

    def check(self, config: dict) -> list[str]:
        settings = (config.get("methods") or {}).get(self.name)
        if settings is None:
            return []
        out = [f"methods.centroid.{k}: unknown key (allowed: {', '.join(DEFAULTS)})" for k in settings
               if k not in DEFAULTS]
        cls = settings.get("cls")
        if cls is not None and cls not in config["classes"]:
            out.append(f"methods.centroid.cls: {cls!r} is not one of classes {config['classes']}")
        return out

    def load(self, method: Method, resources):
        s = method.settings

        def detector(xyz):
            t0 = time.perf_counter()
            box = centroid_box(np.asarray(xyz, dtype=np.float64), float(s["min_height_m"]), float(s["cell_m"]))
            dets = [] if box is None else [{"cls": s["cls"], "box": box, "score": 1.0}]
            return dets, {"seconds": {"total": time.perf_counter() - t0}}

        return detector


methods.register(Centroid())
