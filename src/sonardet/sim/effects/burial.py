"""Object burial (stage ``scene``; key `scenes.realism.burial_m`): settled objects sink into the
sediment by a depth drawn uniformly from burial_m = (min, max) (m). Objects of one arrangement group
(group >= 0: a pile, a stack, a cone cluster) sink together by one depth; scattered objects (group
-1) draw their own. Applied after the physics (which knows no sediment) by the scene builders
(:func:`sonardet.sim.scene.simulate_scene`, :func:`sonardet.sim.hybrid.simulate_hybrid_scene`)
through :func:`bury_objects`.

Point-stage form: :func:`burial_dz` (the points of a sunk object move down with it).
"""

from __future__ import annotations

import numpy as np

from .base import Effect, Key, min_max_range


def burial_depths(groups, burial_m, rng: np.random.Generator) -> np.ndarray:
    """Depth (m, >= 0) by which each object sinks into the sediment, drawn uniformly from
    burial_m = (min, max). Objects of one arrangement group (group >= 0: a pile, a stack, a cone
    cluster) sink together by one depth; scattered objects (group -1) draw their own."""
    groups = np.asarray(groups, dtype=np.int64)
    lo, hi = float(burial_m[0]), float(burial_m[1])
    if lo < 0 or hi < lo:
        raise ValueError(f"scenes.realism.burial_m must be [min, max] with 0 <= min <= max, got {list(burial_m)}")
    own = rng.uniform(lo, hi, len(groups))
    uniq = np.unique(groups[groups >= 0])
    per_group = rng.uniform(lo, hi, len(uniq))
    shared = per_group[np.searchsorted(uniq, np.maximum(groups, 0))] if len(uniq) else own
    return np.where(groups >= 0, shared, own)


def bury_objects(kept, groups, burial_m, rng: np.random.Generator):
    """Sink settled objects kept [(spawn index, t (3,) m, q (4,))] of arrangement groups `groups`
    (one per entry of kept) by a depth drawn per group from burial_m [min, max] (m).
    Returns (kept with lowered t, depths (K,) m or None when burial is off)."""
    if not kept or max(burial_m) <= 0:
        return kept, None
    buried = burial_depths(groups, burial_m, rng)
    return [(k, np.asarray(t, dtype=np.float64) - [0.0, 0.0, d], q) for (k, t, q), d in zip(kept, buried)], buried


def burial_dz(object_index: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
    """Elevation change (m, (n,)) of points of the objects object_index (n,) (index into depth_m
    (K,), -1 for points of no object) when object k sinks by depth_m[k] (m): -depth, 0 for -1."""
    object_index = np.asarray(object_index)
    if len(depth_m) == 0:
        return np.zeros(len(object_index))
    return np.where(object_index >= 0, -np.asarray(depth_m, np.float64)[np.maximum(object_index, 0)], 0.0)


BURIAL = Effect(
    name="burial", stage="scene", doc=__doc__,
    keys=(Key("burial_m", (0.0, 0.0), "m", "depth (m) by which settled objects sink into the sediment, uniform "
              "in [min, max]; one depth per pile, stack or cone cluster, one per scattered object; [0, 0] = off",
              {"type": "array", "items": {"$ref": "#/definitions/nonneg"}, "minItems": 2, "maxItems": 2},
              (min_max_range,), tuple),),
    is_on=lambda scene_realism: max(scene_realism.get("burial_m", (0.0, 0.0))) > 0,
)
