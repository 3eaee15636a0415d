"""Extra dropouts at the outer beams (stage ``sounding``): a probability rising quadratically with
beam angle from 0 at `outer_dropout_start_deg` to `outer_dropout_prob` at the swath edge, added to
the sensor's own random and grazing dropouts (one draw per beam for all of them)."""

from __future__ import annotations

import numpy as np

from .base import Effect, Key, ScanSetup, angle_below_90, probability


def outer_dropout_probability(prob: float, start_deg: float, angles_rad: np.ndarray,
                              half_swath_rad: float) -> np.ndarray:
    """Extra dropout probability per beam (B,) at angles_rad (rad): 0 inside start_deg (deg), rising
    quadratically to prob at the swath edge half_swath_rad (rad)."""
    start = np.deg2rad(start_deg)
    if prob <= 0 or start >= half_swath_rad:
        return np.zeros(len(angles_rad))
    u = np.clip((np.abs(angles_rad) - start) / (half_swath_rad - start), 0.0, 1.0)
    return prob * u * u


def _setup(cfg, setup: ScanSetup) -> None:
    setup.add_dropout_probability(outer_dropout_probability(cfg.outer_dropout_prob, cfg.outer_dropout_start_deg,
                                                            setup.angles_rad, setup.half_swath_rad))


OUTER_DROPOUTS = Effect(
    name="outer_dropouts", stage="sounding", order=50, doc=__doc__,
    keys=(
        Key("outer_dropout_prob", 0.0, "", "extra dropout probability reached at the swath edge, rising "
            "quadratically from outer_dropout_start_deg", {"type": "number", "minimum": 0, "maximum": 1},
            (probability,)),
        Key("outer_dropout_start_deg", 45.0, "deg", "beam angle where the extra outer dropouts start (deg)",
            {"type": "number", "minimum": 0, "exclusiveMaximum": 90}, (angle_below_90,)),
    ),
    switches=("outer_dropout_prob",), setup=_setup,
)
