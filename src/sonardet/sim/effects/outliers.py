"""Outliers (spikes; stage ``sounding``).

A share `outlier_prob` of the soundings (averaged over the swath's beams) is moved along its beam by
+-U(0.1, 1) x `outlier_magnitude_m`; the probability per beam grows as |angle / half swath| **
`outlier_outer_power`, so spikes concentrate at the outer beams.

Point-stage form: :func:`draw_spikes` (which points are spikes and by how much they move; SASA's
domain randomisation draws upward fliers with it).
"""

from __future__ import annotations

import numpy as np

from .base import Effect, Key, ScanChunk, ScanSetup, non_negative, probability


def angle_weight(angles_rad: np.ndarray, half_swath_rad: float, power: float) -> np.ndarray:
    """|angle / half swath| ** power per beam (1 everywhere for power 0); angles in rad."""
    return np.abs(np.asarray(angles_rad) / half_swath_rad) ** power


def outlier_probability(prob: float, power: float, angles_rad: np.ndarray, all_angles_rad: np.ndarray,
                        half_swath_rad: float) -> np.ndarray:
    """Spike probability per beam of angles_rad (rad), growing as |angle / half swath| ** power and
    normalised so its mean over the full fan all_angles_rad is `prob` (capped at 1)."""
    if prob <= 0:
        return np.zeros(len(angles_rad))
    norm = angle_weight(all_angles_rad, half_swath_rad, power).mean()
    if norm <= 0:  # a single nadir beam with power > 0
        return np.full(len(angles_rad), prob)
    w = angle_weight(angles_rad, half_swath_rad, power) / norm
    return np.minimum(prob * w, 1.0)


def draw_spikes(shape, p, magnitude_m: float, rng: np.random.Generator, low_fraction: float = 0.1,
                p_negative: float = 0.5):
    """Which entries of an array of `shape` are spikes (probability p, broadcast against shape) and
    their displacement (m): U(low_fraction, 1) x magnitude_m, negative with probability p_negative.

    Returns (is_spike bool, offset_m float64), both of `shape`; offset_m is drawn for every entry.
    """
    u = rng.random(shape)
    size = rng.uniform(low_fraction, 1.0, shape) * magnitude_m
    sign = np.where(rng.random(shape) < p_negative, -1.0, 1.0)
    return u < p, sign * size


def outlier_offsets(shape, p_beam: np.ndarray, magnitude_m: float, rng: np.random.Generator) -> np.ndarray:
    """Range offsets (m, shape (P,B)): +-U(0.1, 1) x magnitude_m with probability p_beam (B,), else 0."""
    spike, offset = draw_spikes(shape, p_beam[None, :], magnitude_m, rng)
    return np.where(spike, offset, 0.0)


def _setup(cfg, setup: ScanSetup) -> None:
    setup.values["outliers"] = outlier_probability(cfg.outlier_prob, cfg.outlier_outer_power, setup.angles_rad,
                                                   setup.all_angles_rad, setup.half_swath_rad)


def _apply(cfg, setup: ScanSetup, chunk: ScanChunk, rng: np.random.Generator) -> None:
    offsets = outlier_offsets(chunk.r.shape, setup.values["outliers"], cfg.outlier_magnitude_m, rng)
    chunk.r = np.maximum(chunk.r + offsets, 0.0)


OUTLIERS = Effect(
    name="outliers", stage="sounding", order=60, doc=__doc__,
    keys=(
        Key("outlier_prob", 0.0, "", "share of soundings that are spikes (mean over the swath's beams)",
            {"type": "number", "minimum": 0, "maximum": 1}, (probability,)),
        Key("outlier_magnitude_m", 0.5, "m", "spikes move along the beam by +-U(0.1, 1) times this (m)",
            {"$ref": "#/definitions/nonneg"}, (non_negative,)),
        Key("outlier_outer_power", 2.0, "", "spike probability grows as |beam angle / half swath| ** power "
            "(0 = uniform)", {"$ref": "#/definitions/nonneg"}, (non_negative,)),
    ),
    switches=("outlier_prob",), setup=_setup, apply=_apply,
)
