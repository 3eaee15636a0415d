"""Attitude and heave (stage ``ray``).

Per-line roll and pitch biases (a fixed part plus a random per-line part), roll, pitch and yaw
sinusoids and heave. The rays leave the transducer with the true attitude and position; the
soundings are georeferenced with the nominal ones, so a bias shows as a tilt: a roll bias phi moves
a sounding at across-track distance y on a flat seabed vertically by about y tan(phi) (positive
roll raises the starboard side), and a heave h (+ up) lowers the soundings by h. With
`motion_compensated` the sinusoids and heave are known to the georeferencing and only the biases
are errors; the motion then only moves where the beams land.

Point-stage forms (for effects on georeferenced points, e.g. SASA's domain randomisation):
:func:`roll_bias_dz`, :func:`heave_dz` of a :func:`sinusoid`.
"""

from __future__ import annotations

import numpy as np

from .base import (
    HEAVE,
    PITCH,
    ROLL,
    YAW,
    Effect,
    Key,
    Reach,
    ScanSetup,
    finite,
    non_negative,
    positive,
)


def sinusoid(amplitude, period, t, phase):
    """amplitude * sin(2 pi t / period + phase): t and period in one unit (s, or m along a track),
    phase (rad); broadcasts."""
    w = 2.0 * np.pi * t
    return amplitude * np.sin(w / period + phase)


def motion(cfg, t_s: np.ndarray, phase: np.ndarray):
    """Sinusoidal roll, pitch, yaw (rad) and heave (m, + up), each (P,), at ping times t_s (s) with
    per-ping phases (P, 4) (rad; roll, pitch, yaw, heave) of the profile `cfg`."""
    return (sinusoid(np.deg2rad(cfg.roll_amplitude_deg), cfg.roll_period_s, t_s, phase[:, ROLL]),
            sinusoid(np.deg2rad(cfg.pitch_amplitude_deg), cfg.pitch_period_s, t_s, phase[:, PITCH]),
            sinusoid(np.deg2rad(cfg.yaw_amplitude_deg), cfg.yaw_period_s, t_s, phase[:, YAW]),
            sinusoid(cfg.heave_amplitude_m, cfg.heave_period_s, t_s, phase[:, HEAVE]))


def roll_bias_dz(starboard_m, roll_rad):
    """Elevation change (m, + up) of a flat-seabed sounding starboard_m (m, + starboard) across the
    track when the data are georeferenced without a roll bias roll_rad (rad, + starboard down):
    starboard_m tan(roll_rad)."""
    return np.multiply(np.tan(roll_rad), starboard_m)


def heave_dz(heave_m):
    """Elevation change (m, + up) of the soundings of a ping whose transducer was heave_m (m, + up)
    off its nominal height when the georeferencing does not know it: -heave_m."""
    return np.negative(heave_m)


def _setup(cfg, setup: ScanSetup) -> None:
    z, li = setup.lines.normal, setup.line_index
    roll_bias = np.deg2rad(cfg.roll_bias_deg + cfg.roll_bias_sigma_deg * z[:, ROLL])
    pitch_bias = np.deg2rad(cfg.pitch_bias_deg + cfg.pitch_bias_sigma_deg * z[:, PITCH])
    roll, pitch, yaw, heave = motion(cfg, setup.t_s, setup.lines.phase[li])
    setup.roll_rad, setup.pitch_rad = roll_bias[li] + roll, pitch_bias[li] + pitch
    setup.yaw_rad, setup.heave_m = yaw, heave
    if cfg.motion_compensated and any(np.any(a != 0) for a in (roll, pitch, yaw, heave)):
        setup.georef_motion = (roll, pitch, yaw, heave)


def _check(cfg) -> str | None:
    if abs(cfg.roll_bias_deg) >= 45 or abs(cfg.pitch_bias_deg) >= 45:
        return "sensor.realism.roll_bias_deg and pitch_bias_deg must be within +-45 deg"
    return None


def _reach(cfg, half_swath_rad: float, sound_speed_mps: float) -> Reach:
    """Random per-line biases count at 4 sigma."""
    return Reach(across_deg=abs(cfg.roll_bias_deg) + 4 * cfg.roll_bias_sigma_deg + cfg.roll_amplitude_deg,
                 along_deg=abs(cfg.pitch_bias_deg) + 4 * cfg.pitch_bias_sigma_deg + cfg.pitch_amplitude_deg,
                 up_m=cfg.heave_amplitude_m, yaw_deg=cfg.yaw_amplitude_deg)


def _number(lo, hi):
    return {"type": "number", "minimum": lo, "maximum": hi}


_POSITIVE = {"$ref": "#/definitions/positive"}

ATTITUDE = Effect(
    name="attitude", stage="ray", order=10, doc=__doc__, steers=True,
    keys=(
        Key("roll_bias_deg", 0.0, "deg", "uncompensated roll bias of every line (deg, + starboard down, which "
            "raises the starboard side)", _number(-10, 10), (finite,)),
        Key("roll_bias_sigma_deg", 0.0, "deg", "std of an extra random roll bias drawn per line (deg)",
            _number(0, 10), (non_negative,)),
        Key("pitch_bias_deg", 0.0, "deg", "uncompensated pitch bias of every line (deg, + bow up)",
            _number(-10, 10), (finite,)),
        Key("pitch_bias_sigma_deg", 0.0, "deg", "std of an extra random pitch bias drawn per line (deg)",
            _number(0, 10), (non_negative,)),
        Key("roll_amplitude_deg", 0.0, "deg", "roll sinusoid amplitude (deg), random phase per line",
            _number(0, 20), (non_negative,)),
        Key("roll_period_s", 2.75, "s", "roll period (s)", _POSITIVE, (positive,)),
        Key("pitch_amplitude_deg", 0.0, "deg", "pitch sinusoid amplitude (deg)", _number(0, 20), (non_negative,)),
        Key("pitch_period_s", 4.0, "s", "pitch period (s)", _POSITIVE, (positive,)),
        Key("yaw_amplitude_deg", 0.0, "deg", "yaw wobble amplitude (deg, + counter-clockwise)", _number(0, 20),
            (non_negative,)),
        Key("yaw_period_s", 10.0, "s", "yaw wobble period (s)", _POSITIVE, (positive,)),
        Key("heave_amplitude_m", 0.0, "m", "heave sinusoid amplitude (m, + up)", _number(0, 5), (non_negative,)),
        Key("heave_period_s", 6.0, "s", "heave period (s)", _POSITIVE, (positive,)),
        Key("motion_compensated", False, "", "false: the data are georeferenced with the nominal attitude, so "
            "the sinusoids and heave are errors; true: they are known (only the biases are errors) and only "
            "move where the beams land", {"type": "boolean"}, (), bool),
    ),
    switches=("roll_bias_deg", "roll_bias_sigma_deg", "pitch_bias_deg", "pitch_bias_sigma_deg",
              "roll_amplitude_deg", "pitch_amplitude_deg", "yaw_amplitude_deg", "heave_amplitude_m"),
    check=_check, reach=_reach, setup=_setup,
)
