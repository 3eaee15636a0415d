"""Object roughness / biofouling (stage ``range``), per sub-ray: hits on meshes with id >= 0 (the
reef objects in scenes and templates; seabed and rocks carry negative ids) move along the ray as if
the surface were displaced along its normal by N(0, sigma^2), so the distance of such a hit to the
mesh has RMS about sigma. The displacement is independent from hit to hit (no spatial correlation).

Point-stage form: :func:`roughness_point_offsets` (points without normals: an isotropic
N(0, sigma^2) displacement per axis, whose component along any normal is N(0, sigma^2)).
"""

from __future__ import annotations

import numpy as np

from .base import Effect, Key, ScanChunk, ScanSetup, non_negative

#: Smallest |cos(incidence)| used to turn a normal displacement into a range change (about 78 deg),
#: so grazing hits on a rough surface do not jump by metres.
MIN_COS_INCIDENCE = 0.2


def surface_displacement(shape, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """N(0, sigma_m^2) displacements (m) of a rough surface, independent per entry of `shape`."""
    return sigma_m * rng.standard_normal(shape)


def roughness_range_offsets(t, mesh_id, cos_incidence, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """Range changes (m, shape of t) of hits on a surface displaced along its normal by N(0, sigma_m^2):
    d / |cos(incidence)| for hits on meshes with id >= 0, 0 elsewhere."""
    d = surface_displacement(np.shape(t), sigma_m, rng)
    on_object = np.isfinite(t) & (np.asarray(mesh_id) >= 0)
    return np.where(on_object, d / np.maximum(np.abs(cos_incidence), MIN_COS_INCIDENCE), 0.0)


def roughness_point_offsets(n: int, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """Displacements (m, (n, 3)) of n object points of unknown normal: N(0, sigma_m^2) per axis."""
    return surface_displacement((n, 3), sigma_m, rng)


def _apply(cfg, setup: ScanSetup, chunk: ScanChunk, rng: np.random.Generator) -> None:
    chunk.t = chunk.t + roughness_range_offsets(chunk.t, chunk.mesh, chunk.cos_incidence,
                                                cfg.object_roughness_sigma_m, rng)


ROUGHNESS = Effect(
    name="roughness", stage="range", order=40, doc=__doc__,
    keys=(Key("object_roughness_sigma_m", 0.0, "m", "roughness / biofouling: std of a random normal displacement "
              "of object surfaces (mesh id >= 0) per sub-ray hit (m)", {"$ref": "#/definitions/nonneg"},
              (non_negative,)),),
    switches=("object_roughness_sigma_m",), apply=_apply,
)
