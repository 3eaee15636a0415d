"""Refraction: two effects of one ablation group, ``refraction``.

* Surface sound-speed error (stage ``ray``): a flat receive array steers with the sound speed it
  assumes, c_a = c + error, so by Snell's law the true angle obeys sin(a_true) = sin(a) c / c_a
  while the sounding is placed at a. An assumed speed above the true one steers the beams too
  little and the outer beams rise (a smile); below, they sink (a frown). Ranges are unaffected.
* Water-column sound-speed (SVP) bias (stage ``point``): the sounding's elevation changes by
  k D (1 / cos(a) - 1), with D its depth below the transducer and a its vertical beam angle, so
  k > 0 raises the outer beams (a smile). k is `svp_bias_coeff` plus a random per-line part;
  k = 0.0073 gives 1 % of the depth at 65 deg, the size reported for modelled instead of
  measured profiles.

Point-stage form: :func:`svp_bias_dz` (on a flat seabed at depth D, cos a = D / hypot(D, y) at
across-track distance y: :func:`flat_seabed_cos`).
"""

from __future__ import annotations

import numpy as np

from .base import SVP, Effect, Key, Reach, ScanChunk, ScanSetup, finite, non_negative


def steered_angles(angles_rad: np.ndarray, error_mps: float, sound_speed_mps: float) -> np.ndarray:
    """True across-track angles (rad) of beams steered to `angles_rad` (rad) with the assumed sound
    speed sound_speed_mps + error_mps (m/s) when the water's is sound_speed_mps (Snell)."""
    assumed = sound_speed_mps + error_mps
    if assumed <= 0:
        raise ValueError("sensor.realism.surface_sound_speed_error_mps makes the assumed sound speed <= 0")
    return np.arcsin(np.clip(np.sin(angles_rad) * (sound_speed_mps / assumed), -1.0, 1.0))


def svp_bias_dz(k, depth_m, cos_vertical) -> np.ndarray:
    """Elevation change (m, + up) of the water-column sound-speed bias: k D (1/cos a - 1) for depth
    D (m) below the transducer and vertical beam angle a (cos_vertical = cos a)."""
    return k * depth_m * (1.0 / np.maximum(cos_vertical, 1e-6) - 1.0)


def flat_seabed_cos(depth_m, across_m) -> np.ndarray:
    """cos of the vertical angle (unitless) of a beam reaching a flat seabed depth_m (m) below the
    transducer at across-track distance across_m (m)."""
    return depth_m / np.hypot(depth_m, across_m)


def _setup_surface(cfg, setup: ScanSetup) -> None:
    setup.across_rad = steered_angles(setup.angles_rad, cfg.surface_sound_speed_error_mps, setup.sound_speed_mps)


def _reach_surface(cfg, half_swath_rad: float, sound_speed_mps: float) -> Reach:
    edge = float(steered_angles(np.array([half_swath_rad]), cfg.surface_sound_speed_error_mps, sound_speed_mps)[0])
    return Reach(steer_rad=abs(edge - half_swath_rad))


def _setup_svp(cfg, setup: ScanSetup) -> None:
    k = cfg.svp_bias_coeff + cfg.svp_bias_sigma * setup.lines.normal[:, SVP]
    setup.values["svp_bias"] = k


def _apply_svp(cfg, setup: ScanSetup, chunk: ScanChunk, rng: np.random.Generator) -> None:
    k = setup.values["svp_bias"]
    if not np.any(k != 0):
        return
    cos_v = -chunk.geo_dir[..., 2]
    chunk.add_dz(svp_bias_dz(k[chunk.line_row][:, None], chunk.r * cos_v, cos_v))


SURFACE_SOUND_SPEED = Effect(
    name="surface_sound_speed", stage="ray", order=20, group="refraction", steers=True,
    doc="Surface sound-speed error: Snell steering error of a flat array (see the module docstring).",
    keys=(Key("surface_sound_speed_error_mps", 0.0, "m/s", "sound speed the array assumes for beam steering "
              "minus the true one (m/s); Snell steering error, + gives a smile (outer beams up)",
              {"type": "number", "minimum": -100, "maximum": 100}, (finite,)),),
    switches=("surface_sound_speed_error_mps",), reach=_reach_surface, setup=_setup_surface,
)

SVP_BIAS = Effect(
    name="svp_bias", stage="point", order=90, group="refraction",
    doc="Water-column sound-speed bias k D (1/cos a - 1) (see the module docstring).",
    keys=(
        Key("svp_bias_coeff", 0.0, "", "water-column sound-speed bias k: elevation change k * depth * (1/cos(beam "
            "angle) - 1), + raises outer beams (smile); 0.0073 = 1 % of depth at 65 deg",
            {"type": "number", "minimum": -0.1, "maximum": 0.1}, (finite,)),
        Key("svp_bias_sigma", 0.0, "", "std of an extra random k drawn per line",
            {"type": "number", "minimum": 0, "maximum": 0.1}, (non_negative,)),
    ),
    switches=("svp_bias_coeff", "svp_bias_sigma"), setup=_setup_svp, apply=_apply_svp,
)
