"""Template scans: each object virtually surveyed by the MBES sensor model in its resting pose.

A template view places the object (canonical frame, resting pose) at the origin of a flat seabed at
z = 0 with a given yaw, and runs one straight survey line along x or y at a given across-track
offset, the transducer `altitude_m` above the seabed. Only the object is cast against: a beam that
misses it would hit the flat seabed, which the detectors remove anyway, so the template holds
object points only ("seabed removed by construction") and only the beams and pings that can reach
the object are modelled. Points are stored in the object's canonical frame, so a detector can pose
them directly, together with the view's pose and scan geometry. The files are read and written by
`sonardet.io.templates` (`read_templates`, `write_templates`).
"""

from __future__ import annotations

import numpy as np

from ..geometry import quat_from_yaw, quat_to_matrix
from ..io.templates import TemplateViews
from .mbes import RaycastTarget, SensorConfig, Trajectory, beam_angles, ping_rate_hz, scan


def scan_template_view(vertices, faces, radius_m: float, height_m: float, yaw_rad: float, direction: str,
                       offset_m: float, altitude_m: float, sensor: SensorConfig,
                       rng: np.random.Generator, margin_m: float = 0.5):
    """Scan one view; returns (canonical points (K,3), ping (K,), beam (K,), t (3,), q (4,)).

    radius_m is the object's horizontal radius about its canonical z axis and height_m its height;
    they bound the pings and beams that are cast.
    """
    q = quat_from_yaw(yaw_rad)
    r = quat_to_matrix(q)
    target = RaycastTarget([(np.asarray(vertices) @ r.T, faces)])
    heading = 0.0 if direction == "x" else 0.5 * np.pi
    along = np.array([np.cos(heading), np.sin(heading)])
    stbd = np.array([np.sin(heading), -np.cos(heading)])
    # The track passes offset_m to port of the object, so the object lies offset_m to starboard.
    track_xy = -offset_m * stbd
    span = radius_m + margin_m
    step = sensor.speed_mps / ping_rate_hz(sensor, altitude_m)
    s = np.arange(-span, span + 1e-9, step)
    pos = np.c_[track_xy + s[:, None] * along, np.full(len(s), altitude_m)]
    # Beams whose ray passes over the object's across-track span between its top and the seabed.
    ang = beam_angles(sensor)
    x_lo, x_hi = offset_m - span, offset_m + span
    near = altitude_m - height_m - margin_m
    xs_top, xs_bot = max(near, 0.0) * np.tan(ang), altitude_m * np.tan(ang)
    sel = np.flatnonzero((np.maximum(xs_top, xs_bot) >= x_lo) & (np.minimum(xs_top, xs_bot) <= x_hi))
    traj = Trajectory(pos, np.full(len(s), heading), np.zeros(len(s), np.int32))
    snd = scan(target, traj, sensor, rng, beams=sel)
    canonical = snd.xyz @ r  # R^T p, as rows
    return canonical, snd.ping, snd.beam, np.zeros(3), q


def scan_templates(cls: str, vertices, faces, symmetry_order: int, cfg: dict, sensor: SensorConfig,
                   rng: np.random.Generator) -> TemplateViews:
    """Scan every view of a class: yaw angles x line directions x across-track offsets from `cfg`
    (the `templates` config section). Continuous symmetry needs a single yaw; n-fold symmetry only
    yaws within one period (2 pi / n), so yaws beyond it are folded and de-duplicated."""
    v = np.asarray(vertices, dtype=np.float64)
    radius = float(np.max(np.hypot(v[:, 0], v[:, 1])))
    height = float(v[:, 2].max() - v[:, 2].min())
    yaws = np.deg2rad(np.asarray(cfg["yaw_deg"], dtype=np.float64))
    if symmetry_order == 0:
        yaws = yaws[:1] * 0.0
    elif symmetry_order > 1:
        yaws = np.unique(np.round(np.mod(yaws, 2 * np.pi / symmetry_order), 9))
    pts, view, ping, beam = [], [], [], []
    meta = {k: [] for k in ("yaw", "dir", "off", "t", "q")}
    k = 0
    for yaw in yaws:
        for direction in cfg["directions"]:
            for off in cfg["offsets_m"]:
                p, pg, bm, t, q = scan_template_view(v, faces, radius, height, float(yaw), direction, float(off),
                                                     cfg["altitude_m"], sensor, rng)
                pts.append(p)
                view.append(np.full(len(p), k, np.int32))
                ping.append(pg)
                beam.append(bm)
                for key, val in zip(("yaw", "dir", "off", "t", "q"), (yaw, direction, off, t, q)):
                    meta[key].append(val)
                k += 1
    return TemplateViews(
        cls=cls,
        xyz=np.concatenate(pts),
        view=np.concatenate(view),
        ping=np.concatenate(ping),
        beam=np.concatenate(beam),
        yaw_rad=np.asarray(meta["yaw"], dtype=np.float64),
        direction=np.asarray(meta["dir"]),
        offset_m=np.asarray(meta["off"], dtype=np.float64),
        pose_t=np.asarray(meta["t"]),
        pose_q=np.asarray(meta["q"]),
        scan_params={"altitude_m": cfg["altitude_m"], "sensor": sensor.to_dict()},
    )
