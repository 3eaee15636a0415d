"""Range quantisation (stage ``sounding``): reported ranges are rounded to multiples of
`range_quantum_m` (an R2Sonic 2026 reports 0.0029 m steps); 0 is off."""

from __future__ import annotations

import numpy as np

from .base import Effect, Key, ScanChunk, ScanSetup, non_negative


def quantise(r: np.ndarray, step_m: float) -> np.ndarray:
    """Ranges r (m) rounded to multiples of step_m (m); unchanged for step_m = 0."""
    if step_m <= 0:
        return r
    return np.round(np.asarray(r, dtype=np.float64) / step_m) * step_m


def _apply(cfg, setup: ScanSetup, chunk: ScanChunk, rng: np.random.Generator) -> None:
    chunk.r = quantise(chunk.r, cfg.range_quantum_m)


QUANTISATION = Effect(
    name="quantisation", stage="sounding", order=70, doc=__doc__,
    keys=(Key("range_quantum_m", 0.0, "m", "reported ranges are rounded to multiples of this step (m; R2Sonic "
              "2026: 0.0029); 0 = off", {"$ref": "#/definitions/nonneg"}, (non_negative,)),),
    switches=("range_quantum_m",), apply=_apply,
)
