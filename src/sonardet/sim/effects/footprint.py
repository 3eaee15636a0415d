"""Beam footprint and bottom detection (stage ``sounding``).

Each beam is a bundle of sub-rays on a regular grid over its across x along beamwidth (the -3 dB
full widths), weighted by a Gaussian beam pattern that falls to 1/2 at the grid's edge. The beam's
range combines the sub-ray ranges: 'amplitude' detection takes their weighted mean (rounds edges,
fills small holes partly), 'phase' their weighted median (a hole with less than half of the beam's
weight is not seen), 'first' the shortest (first arrival), and 'auto' switches from amplitude to
phase beyond `detection_switch_deg` like an R2Sonic. A beam whose hit sub-rays hold less than half
of its weight gives no sounding. The mesh id and normal of a beam are those of the sub-ray whose
range is nearest the combined one. 1 x 1 sub-rays (the default) is a single ray: off.
"""

from __future__ import annotations

import numpy as np

from .base import (
    Effect,
    Key,
    Reach,
    ScanSetup,
    angle_below_90,
    integer_at_least,
    one_of,
    positive,
)

DETECTION_MODES = ("amplitude", "phase", "first", "auto")


def n_subrays(cfg) -> int:
    """Sub-rays per beam: footprint_n_across x footprint_n_along."""
    return int(cfg.footprint_n_across) * int(cfg.footprint_n_along)


def subray_bundle(cfg):
    """Sub-ray offsets (rad) across and along track and weights (sum 1), each (S,), S = n_across * n_along.

    The offsets lie on a regular grid spanning the full -3 dB beamwidths; the weights follow a
    Gaussian beam pattern that is 1/2 at the grid's edge in each direction (1 for a single ray).
    """
    def axis(n, width_deg):
        if n == 1:
            return np.zeros(1), np.ones(1)
        u = np.linspace(-1.0, 1.0, n)
        return u * np.deg2rad(0.5 * width_deg), np.exp(-np.log(2.0) * u * u)

    da, wa = axis(int(cfg.footprint_n_across), cfg.beamwidth_across_deg)
    dl, wl = axis(int(cfg.footprint_n_along), cfg.beamwidth_along_deg)
    w = (wa[:, None] * wl[None, :]).ravel()
    return np.repeat(da, len(dl)), np.tile(dl, len(da)), w / w.sum()


def combine_subrays(t: np.ndarray, weight: np.ndarray, phase_beam: np.ndarray, first: bool = False):
    """Detect one range per beam from its sub-ray ranges.

    t (P,B,S) sub-ray ranges (m, inf = miss); weight (S,) sub-ray weights; phase_beam (B,) bool:
    weighted median (phase) where True, weighted mean (amplitude) elsewhere; first=True takes the
    shortest range instead. Returns (range (P,B) float64, index (P,B) of the sub-ray nearest the
    range, detected (P,B) bool: the hit sub-rays hold at least half of the beam's weight).
    """
    t = np.asarray(t, dtype=np.float64)
    valid = np.isfinite(t)
    w = np.where(valid, weight[None, None, :], 0.0)
    wsum = w.sum(-1)
    detected = wsum >= 0.5 * weight.sum() - 1e-12
    tz = np.where(valid, t, 0.0)
    if first:
        r = np.min(t, axis=-1)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            r = (w * tz).sum(-1) / wsum
        if np.any(phase_beam):
            order = np.argsort(t, axis=-1, kind="stable")
            cw = np.cumsum(np.take_along_axis(w, order, -1), -1)
            k = np.argmax(cw >= 0.5 * wsum[..., None], axis=-1)
            med = np.take_along_axis(t, np.take_along_axis(order, k[..., None], -1), -1)[..., 0]
            r = np.where(phase_beam[None, :], med, r)
    r = np.where(detected, r, np.inf)
    with np.errstate(invalid="ignore"):
        idx = np.argmin(np.where(valid, np.abs(t - r[..., None]), np.inf), axis=-1)
    return r, idx, detected


def phase_beams(cfg, angles_rad: np.ndarray) -> np.ndarray:
    """(B,) bool: beams at angles_rad (rad) detected by weighted median ('phase', or 'auto' beyond
    detection_switch_deg)."""
    if cfg.detection == "auto":
        return np.abs(angles_rad) > np.deg2rad(cfg.detection_switch_deg)
    return np.full(len(angles_rad), cfg.detection == "phase")


def _setup(cfg, setup: ScanSetup) -> None:
    setup.sub_across_rad, setup.sub_along_rad, setup.sub_weight = subray_bundle(cfg)
    setup.phase_beam = phase_beams(cfg, setup.angles_rad)
    setup.first = cfg.detection == "first"


def _reach(cfg, half_swath_rad: float, sound_speed_mps: float) -> Reach:
    return Reach(across_deg=0.5 * cfg.beamwidth_across_deg, along_deg=0.5 * cfg.beamwidth_along_deg)


FOOTPRINT = Effect(
    name="footprint", stage="sounding", order=30, doc=__doc__,
    keys=(
        Key("footprint_n_across", 1, "", "beam footprint: sub-rays across track per beam; with footprint_n_along, "
            "1 x 1 = a single ray (off); cost: n_across x n_along times the rays",
            {"type": "integer", "minimum": 1, "maximum": 15}, (integer_at_least(1),), int),
        Key("footprint_n_along", 1, "", "beam footprint: sub-rays along track per beam",
            {"type": "integer", "minimum": 1, "maximum": 15}, (integer_at_least(1),), int),
        Key("beamwidth_across_deg", 0.5, "deg", "receive beamwidth, -3 dB full width (deg); the sub-rays span it, "
            "Gaussian-weighted (1/2 at the edge)", {"$ref": "#/definitions/positive"}, (positive,)),
        Key("beamwidth_along_deg", 1.0, "deg", "transmit beamwidth, -3 dB full width (deg)",
            {"$ref": "#/definitions/positive"}, (positive,)),
        Key("detection", "amplitude", "", "range from the sub-rays: amplitude = weighted mean, phase = weighted "
            "median, first = shortest, auto = amplitude inside detection_switch_deg and phase beyond",
            {"enum": list(DETECTION_MODES)}, (one_of(*DETECTION_MODES),), str),
        Key("detection_switch_deg", 30.0, "deg", "detection 'auto': |beam angle| (deg) beyond which phase "
            "detection is used", {"type": "number", "minimum": 0, "exclusiveMaximum": 90}, (angle_below_90,)),
    ),
    is_on=lambda cfg: n_subrays(cfg) > 1, reach=_reach, setup=_setup,
)
