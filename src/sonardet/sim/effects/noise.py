"""The sensor's own range noise (`sensor.range_sigma_m`; not a realism effect, it is always on):
N(0, sigma^2) along each beam, drawn in float32 as the scan draws it.

Point-stage form: :func:`range_noise_dz` (a near-vertical beam: the elevation moves by minus the
range error).
"""

from __future__ import annotations

import numpy as np


def range_noise(shape, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """Range errors (m, float32, `shape`): sigma_m x standard normals drawn in float32."""
    return np.float32(sigma_m) * rng.standard_normal(shape, dtype=np.float32)


def range_noise_dz(n: int, sigma_m: float, rng: np.random.Generator, cos_vertical=1.0) -> np.ndarray:
    """Elevation changes (m, (n,) float64) of n soundings from their range noise (:func:`range_noise`)
    along beams with cos(vertical angle) cos_vertical: -error x cos_vertical."""
    return -range_noise((n,), sigma_m, rng).astype(np.float64) * cos_vertical
