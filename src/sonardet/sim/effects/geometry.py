"""Ray geometry shared by the effects and the realistic scan: ping times, beam directions under an
attitude, and how far an effect profile lets the rays reach beyond the nominal swath.

Frames and units: see :mod:`sonardet.sim.effects.base`. A beam's body-frame direction is
(sin b, cos b sin a, cos b cos a) for across-track angle a and along-track angle b; the attitude
rotates it as Ry(pitch) Rx(roll), then the heading maps it into the scene frame.
"""

from __future__ import annotations

import numpy as np

from .base import STAGES, Reach
from .registry import pipeline


def ping_times_s(position: np.ndarray, line: np.ndarray, speed_mps: float) -> np.ndarray:
    """Time (s, (P,)) of each ping since the first ping of its line: along-track distance / speed.

    position (P, 3) m, line (P,) survey line per ping, speed_mps the vessel speed (m/s)."""
    position = np.asarray(position, dtype=np.float64)
    step = np.r_[0.0, np.linalg.norm(np.diff(position[:, :2], axis=0), axis=1)]
    start = np.r_[True, line[1:] != line[:-1]]
    step[start] = 0.0
    cum = np.cumsum(step)
    # Restart the clock at each line start.
    first = np.maximum.accumulate(np.where(start, np.arange(len(step)), 0))
    return (cum - cum[first]) / float(speed_mps)


def fan_directions(heading_rad, roll_rad, pitch_rad, across_rad, along_rad) -> np.ndarray:
    """Unit ray directions (..., 3) in the scene frame, float64.

    heading_rad (counter-clockwise from +x), roll_rad (+ starboard down), pitch_rad (+ bow up) are
    per ping; across_rad (+ starboard) and along_rad (+ forward) are the beam's angles in the array
    frame; all broadcast against each other (e.g. (P,1,1), (1,B,S), (1,1,S)).
    """
    ca, sa = np.cos(across_rad), np.sin(across_rad)
    cb, sb = np.cos(along_rad), np.sin(along_rad)
    bx, by, bz = sb, cb * sa, cb * ca
    cr, sr = np.cos(roll_rad), np.sin(roll_rad)
    by, bz = cr * by - sr * bz, sr * by + cr * bz
    cp, sp = np.cos(pitch_rad), np.sin(pitch_rad)
    bx, bz = cp * bx + sp * bz, -sp * bx + cp * bz
    ch, sh = np.cos(heading_rad), np.sin(heading_rad)
    # Body (forward, starboard, down) to scene: forward (cos h, sin h, 0), starboard (sin h, -cos h, 0).
    return np.stack(np.broadcast_arrays(bx * ch + by * sh, bx * sh - by * ch, -bz), axis=-1)


def total_reach(cfg, half_swath_rad: float, sound_speed_mps: float) -> Reach:
    """The reaches of every registered sensor effect under `cfg`, added in pipeline order."""
    out = Reach()
    for stage in STAGES[1:]:
        for e in pipeline(stage):
            if e.reach is None:
                continue
            r = e.reach(cfg, half_swath_rad, sound_speed_mps)
            out.across_deg += r.across_deg
            out.along_deg += r.along_deg
            out.steer_rad += r.steer_rad
            out.up_m += r.up_m
            out.yaw_deg += r.yaw_deg
    return out


def swath_margin_m(cfg, altitude_m: float, half_swath_rad: float, sound_speed_mps: float) -> float:
    """Extra distance (m) beyond the nominal swath that the rays of the profile `cfg` (a
    RealismConfig or None) can reach on a flat seabed altitude_m (m) below the transducer; 0 for no
    profile or one with every effect off. Geometry culled to the swath needs this margin."""
    if cfg is None or not cfg.active:
        return 0.0
    reach = total_reach(cfg, half_swath_rad, sound_speed_mps)
    across = np.deg2rad(reach.across_deg) + reach.steer_rad
    along = np.deg2rad(reach.along_deg)
    depth = altitude_m + reach.up_m
    edge = min(half_swath_rad + across, np.deg2rad(85.0))
    half_w = depth * np.tan(edge)
    return float(max(half_w - altitude_m * np.tan(half_swath_rad),
                     depth * np.tan(along) + half_w * np.sin(np.deg2rad(reach.yaw_deg))))
