"""Objects unlike their class models: per-object perturbed geometry for the model-mismatch test set.

Real reef elements are not their CAD models: casting tolerances, another tetrapod design, worn or
broken legs, another rib layout or hole pattern, biofouling, burial. Each object of a mismatch scene
gets its own draws (seeded from the scene and the object), recorded in the scene JSON, and its own
mesh, which the detectors never see as a model:

* tetrapods: leg radii x U(leg_scale) at the same overall height; with `broken_prob` one down leg
  shortened by U(0, broken_max_frac) of its length; with `rounded_prob` the leg ends rounded;
* rings: ribs U{ring_ribs} (0 allowed: two free walls), both walls x U(ring_wall_scale);
* cones: the top opening x U(cone_top_scale), another hole pattern (seed and count);
* any object: a fouling shell of U(fouling_m) thickness, uneven (the surface displaced outward along
  its normals by thickness x a smooth random field in [0, 1] over the object);
* burial U(burial_m) is applied in the scene, like the realism test set's.

Ranges are the config's `mismatch_test.perturbations` (:data:`DEFAULT_RANGES`, validated by
:func:`check_ranges`). Units: metres, unitless factors.
"""

from __future__ import annotations

import numpy as np
import trimesh

from . import classes
from .catalog import ObjectInfo, object_info
from .meshes import ObjectModel, build_reef_cone, build_reef_ring, build_tetrapod_variant

__all__ = ["DEFAULT_RANGES", "check_ranges", "draw_perturbation", "foul", "perturbed_object"]

#: Perturbation ranges ([low, high] uniform, probabilities in [0, 1]).
DEFAULT_RANGES = {
    "leg_scale": [0.65, 1.35],
    "broken_prob": 0.3,
    "broken_max_frac": 0.25,
    "rounded_prob": 0.5,
    "ring_ribs": [0, 6],
    "ring_wall_scale": [0.7, 1.3],
    "cone_top_scale": [0.85, 1.3],
    "cone_holes": [20, 40],
    "fouling_m": [0.0, 0.05],
    "burial_m": [0.0, 0.3],
}


def check_ranges(r: dict, objects_cfg: dict) -> list[str]:
    """Problems of perturbation ranges that would make an invalid mesh, each naming its key under
    `mismatch_test.perturbations` (e.g. a leg scale <= 0, a leg shortened by its whole length, a wall
    so thick that the ring has no hole, a cone top narrower than its walls)."""
    out = []

    def bad(key, why):
        out.append(f"mismatch_test.perturbations.{key}: {r[key]!r} {why}")

    for key in ("leg_scale", "ring_wall_scale", "cone_top_scale", "fouling_m", "burial_m", "ring_ribs", "cone_holes"):
        lo, hi = r[key]
        if lo > hi:
            bad(key, "has low > high")
    if r["leg_scale"][0] <= 0:
        bad("leg_scale", "must stay > 0 (a leg needs a thickness)")
    if not 0.0 <= r["broken_max_frac"] < 0.9:
        bad("broken_max_frac", "must be in [0, 0.9): a leg shortened by its whole length is not a leg")
    for key in ("broken_prob", "rounded_prob"):
        if not 0.0 <= r[key] <= 1.0:
            bad(key, "must be a probability in [0, 1]")
    if r["fouling_m"][0] < 0 or r["burial_m"][0] < 0 or r["ring_ribs"][0] < 0 or r["cone_holes"][0] < 0:
        bad("fouling_m" if r["fouling_m"][0] < 0 else "burial_m" if r["burial_m"][0] < 0 else "ring_ribs",
            "must not be negative")
    ring = classes.class_params("reef_ring", objects_cfg) if "reef_ring" in classes.names() else None
    if ring is not None:
        inner = 0.5 * ring["outer_diameter_m"] - r["ring_wall_scale"][1] * (ring["outer_wall_m"] + ring["inner_wall_m"])
        if inner - ring["gap_m"] <= 0:
            bad("ring_wall_scale", "makes the ring's walls fill its diameter (no inner opening)")
        if r["ring_wall_scale"][0] <= 0:
            bad("ring_wall_scale", "must stay > 0")
    cone = classes.class_params("reef_cone", objects_cfg) if "reef_cone" in classes.names() else None
    if cone is not None and r["cone_top_scale"][0] * cone["top_diameter_m"] <= 2.5 * cone["wall_m"]:
        bad("cone_top_scale", "makes the cone's top opening narrower than its walls")
    return out


def draw_perturbation(cls: str, ranges: dict, rng: np.random.Generator) -> dict:
    """The draws for one object of class `cls` (every draw made for every class, in a fixed order, so
    one range's change does not shift another's draws): a JSON-ready record."""
    u = rng.random(8)
    leg = ranges["leg_scale"][0] + u[0] * (ranges["leg_scale"][1] - ranges["leg_scale"][0])
    broken = bool(u[1] < ranges["broken_prob"])
    rec = {
        "fouling_m": float(ranges["fouling_m"][0] + u[2] * (ranges["fouling_m"][1] - ranges["fouling_m"][0])),
        "fouling_seed": int(rng.integers(0, 2**31 - 1)),
    }
    spec = classes.get(cls)
    if spec.symmetry_order == 3 and len(spec.up_axes) == 4:  # a tetrapod
        rec.update(leg_scale=float(leg), broken_leg=int(1 + int(u[3] * 3)) if broken else None,
                   broken_frac=float(u[4] * ranges["broken_max_frac"]) if broken else 0.0,
                   rounded=bool(u[5] < ranges["rounded_prob"]))
    elif cls == "reef_ring":
        lo, hi = ranges["ring_ribs"]
        rec.update(n_ribs=int(lo + int(u[6] * (hi - lo + 1))),
                   wall_scale=float(ranges["ring_wall_scale"][0] + u[7] * np.diff(ranges["ring_wall_scale"])[0]))
    elif cls == "reef_cone":
        lo, hi = ranges["cone_holes"]
        rec.update(top_scale=float(ranges["cone_top_scale"][0] + u[6] * np.diff(ranges["cone_top_scale"])[0]),
                   n_holes=int(lo + int(u[7] * (hi - lo + 1))), hole_seed=int(rng.integers(0, 2**31 - 1)))
    return rec


def _smooth_field(points: np.ndarray, rng: np.random.Generator, n_waves: int = 6) -> np.ndarray:
    """A smooth random field in [0, 1] over points (K, 3): a sum of plane waves of 0.3-1.2 m."""
    k = rng.normal(size=(n_waves, 3))
    k /= np.linalg.norm(k, axis=1, keepdims=True)
    lam = rng.uniform(0.3, 1.2, n_waves)
    ph = rng.uniform(0, 2 * np.pi, n_waves)
    f = np.sin(points @ (k / lam[:, None]).T * 2 * np.pi + ph).sum(1)
    return (f - f.min()) / max(float(np.ptp(f)), 1e-9)


def foul(mesh: trimesh.Trimesh, thickness_m: float, seed: int, edge_m: float = 0.25) -> trimesh.Trimesh:
    """The mesh with an uneven fouling shell: subdivided to edges of at most edge_m (m; the field's
    waves are 0.3-1.2 m), coincident vertices merged, every vertex moved outward along its normal by
    thickness_m x a smooth random field in [0, 1]. For ray casting (the shell may self-touch where
    the surface is concave)."""
    if thickness_m <= 0:
        return mesh
    v, f = trimesh.remesh.subdivide_to_size(np.asarray(mesh.vertices), np.asarray(mesh.faces), max_edge=edge_m)
    out = trimesh.Trimesh(v, f, process=True)
    field = _smooth_field(np.asarray(out.vertices), np.random.default_rng(seed))
    out.vertices = np.asarray(out.vertices) + np.asarray(out.vertex_normals) * (thickness_m * field)[:, None]
    out.apply_translation([0.0, 0.0, -out.bounds[0, 2]])
    return out


#: Facets around a circle of a perturbed object (the class models use objects.sections, 96 by default):
#: half of it changes a 2 m cone's surface by 1 mm, far below the sonar's footprint, at half the cost.
PERTURBED_SECTIONS = 48


def _shape(cls: str, rec: dict, objects_cfg: dict, base: ObjectInfo) -> ObjectModel:
    """The perturbed shape of a class before fouling (the class model itself for other classes)."""
    p = classes.class_params(cls, objects_cfg)
    objects_cfg = {**objects_cfg, "sections": min(int(objects_cfg["sections"]), PERTURBED_SECTIONS)}
    if "leg_scale" in rec:
        ratio = base.spec["leg_root_radius_m"] / base.spec["leg_length_m"]
        return build_tetrapod_variant(cls, p["height_m"], ratio, p["taper"], objects_cfg["sections"] // 2,
                                      rec["leg_scale"], rec["broken_leg"], rec["broken_frac"], rec["rounded"])
    if "n_ribs" in rec:
        s = rec["wall_scale"]
        return build_reef_ring(p["height_m"], p["outer_diameter_m"], s * p["outer_wall_m"], s * p["inner_wall_m"],
                               p["gap_m"], p["outer_holes"], p["outer_hole_diameter_m"], p["inner_holes"],
                               p["inner_hole_diameter_m"], rec["n_ribs"], p["rib_m"], objects_cfg["holes"],
                               objects_cfg["sections"])
    if "top_scale" in rec:
        return build_reef_cone(p["height_m"], p["base_diameter_m"], rec["top_scale"] * p["top_diameter_m"],
                               p["wall_m"], rec["n_holes"], tuple(p["hole_diameter_m"]), objects_cfg["holes"],
                               rec["hole_seed"], objects_cfg["sections"])
    return ObjectModel(cls, base.mesh, base.convex_parts, base.volume_m3, base.symmetry_order, dict(base.spec))


def perturbed_object(cls: str, rec: dict, objects_cfg: dict, base: ObjectInfo) -> ObjectInfo:
    """The ObjectInfo of one perturbed object (draws `rec`, the class model `base` as read from its
    files): its own mesh (the convex parts of the perturbed shape, without the fouling shell, serve
    the physics)."""
    shape = _shape(cls, rec, objects_cfg, base)
    mesh = foul(shape.mesh, rec["fouling_m"], rec["fouling_seed"])
    model = ObjectModel(cls, mesh, shape.convex_parts, float(mesh.volume), shape.symmetry_order, dict(shape.spec))
    return object_info(model, objects_cfg["density_kg_m3"])
