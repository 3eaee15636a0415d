"""Natural clutter: irregular convex rocks (boulders) for the scene simulator.

A rock is the convex hull of a randomly perturbed, squashed ellipsoid point set: flattened (natural
boulders lie on their broad side), with a random radial jitter that gives it facets and corners. Being
convex, the mesh is its own single convex part for the physics engine (``[mesh.vertices]``).

Frame and units: canonical frame as for the objects (DESIGN.md): metres, z up, the base centre (centre
of the bounding box's bottom face) at the origin. `size_m` is the largest bounding-box extent.
"""

from __future__ import annotations

import numpy as np
import trimesh

#: Density of a typical granite/gneiss boulder (kg/m^3), for rock masses.
ROCK_DENSITY_KG_M3 = 2650.0

#: Size range (largest extent, m) of the rocks this module makes.
ROCK_SIZE_RANGE_M = (0.2, 1.5)


def make_rock(size_m: float, rng: np.random.Generator, n_points: int = 48, jitter: float = 0.25,
              flatness_range=(0.35, 0.75), elongation_range=(0.6, 1.0)) -> trimesh.Trimesh:
    """Irregular convex rock mesh whose largest bounding-box extent is size_m (m), in its canonical frame.

    n_points directions (uniform on the sphere) are scaled by an ellipsoid with axes
    (1, elongation, flatness) drawn from the given ranges, jittered radially by a factor in
    [1 - jitter, 1 + jitter], rotated by a random yaw, and wrapped in their convex hull. The result is
    watertight, convex, float64, with the bounding-box bottom centre at the origin. size_m must lie in
    ROCK_SIZE_RANGE_M (0.2-1.5 m).
    """
    lo, hi = ROCK_SIZE_RANGE_M
    if not lo * (1 - 1e-9) <= size_m <= hi * (1 + 1e-9):
        raise ValueError(f"rock size_m must be in [{lo}, {hi}] m, got {size_m}")
    if n_points < 8:
        raise ValueError(f"n_points must be >= 8, got {n_points}")
    if not 0.0 <= jitter < 1.0:
        raise ValueError(f"jitter must be in [0, 1), got {jitter}")
    d = rng.normal(size=(n_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    axes = np.array([1.0, rng.uniform(*elongation_range), rng.uniform(*flatness_range)])
    r = 1.0 + jitter * rng.uniform(-1.0, 1.0, n_points)
    pts = d * axes * r[:, None]
    yaw = rng.uniform(0.0, 2.0 * np.pi)
    c, s = np.cos(yaw), np.sin(yaw)
    pts = pts @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    mesh = trimesh.convex.convex_hull(pts)
    lo_b, hi_b = mesh.bounds
    mesh.apply_translation(-np.array([0.5 * (lo_b[0] + hi_b[0]), 0.5 * (lo_b[1] + hi_b[1]), lo_b[2]]))
    mesh.apply_scale(size_m / float(np.max(mesh.extents)))
    if not (mesh.is_watertight and mesh.is_volume):
        raise RuntimeError("convex hull of the rock point set is not a closed volume (degenerate draw)")
    return mesh


def make_rocks(n: int, rng: np.random.Generator, size_range_m=ROCK_SIZE_RANGE_M) -> list[trimesh.Trimesh]:
    """n rocks with sizes (largest extent, m) log-uniform in size_range_m (small stones more common)."""
    lo, hi = (float(v) for v in size_range_m)
    if not (ROCK_SIZE_RANGE_M[0] <= lo <= hi <= ROCK_SIZE_RANGE_M[1]):
        raise ValueError(f"size_range_m must lie within {ROCK_SIZE_RANGE_M}, got {size_range_m}")
    sizes = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    return [make_rock(float(s), rng) for s in sizes]


def rock_mass_kg(mesh: trimesh.Trimesh, density_kg_m3: float = ROCK_DENSITY_KG_M3) -> float:
    """Mass (kg) of a rock mesh (m^3) at the given density (kg/m^3)."""
    return float(mesh.volume) * float(density_kg_m3)
