"""Multibeam echosounder (MBES) sensor model: beam fans, survey trajectories and ray-cast soundings.

Frames and units: scene frame, metres, z up; angles in radians unless a name says `_deg`. A ping is a
fan of beams in the vertical plane across the direction of travel; beam angle 0 points straight
down and positive angles point to starboard. Ray casting uses Embree through Open3D's
`RaycastingScene` (float32 internally; scene coordinates are local, so float32 resolves them to
micrometres); the sounding positions are computed in float64 from the float64 transducer position,
the direction and the cast range.

The interface the whole project uses is :func:`scan`:
    (target meshes, trajectory, sensor config, rng) -> soundings with ping, beam, line and mesh ids.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np
import open3d as o3d

from . import realism as rlz
from .realism import RealismConfig

#: Sentinel mesh id of a beam without a return (never appears in the output, documented for users).
NO_HIT = -1


@dataclass(frozen=True)
class SensorConfig:
    """Multibeam sonar settings (the `sensor` section of the config)."""

    n_beams: int = 512
    swath_deg: float = 130.0
    spacing: str = "equiangular"  # or "equidistant" (equal spacing on a flat seabed)
    range_sigma_m: float = 0.01
    dropout_prob: float = 0.005  # beams without return, independent of geometry
    grazing_dropout_prob: float = 0.3  # extra dropout probability reached at 90 deg incidence
    grazing_start_deg: float = 60.0  # incidence angle at which the extra dropout starts
    sound_speed_mps: float = 1500.0
    max_ping_rate_hz: float = 30.0
    speed_mps: float = 2.0
    realism: RealismConfig | None = None  # optional realism profile (None: plain ray cast)

    def __post_init__(self):
        if self.n_beams < 1:
            raise ValueError(f"sensor.n_beams must be >= 1, got {self.n_beams}")
        if not 0.0 < self.swath_deg < 180.0:
            raise ValueError(f"sensor.swath_deg must be in (0, 180), got {self.swath_deg}")
        if self.spacing not in ("equiangular", "equidistant"):
            raise ValueError(f"sensor.spacing must be 'equiangular' or 'equidistant', got {self.spacing!r}")
        if self.range_sigma_m < 0:
            raise ValueError(f"sensor.range_sigma_m must be >= 0, got {self.range_sigma_m}")
        if self.speed_mps <= 0 or self.max_ping_rate_hz <= 0 or self.sound_speed_mps <= 0:
            raise ValueError("sensor.speed_mps, max_ping_rate_hz and sound_speed_mps must be > 0")
        if self.realism is not None and not isinstance(self.realism, RealismConfig):
            object.__setattr__(self, "realism", RealismConfig.from_config(self.realism))

    @classmethod
    def from_dict(cls, d: dict) -> "SensorConfig":
        """Build from a config mapping, ignoring keys that are not sensor settings; a `realism`
        mapping becomes a :class:`~sonardet.sim.realism.RealismConfig`."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})

    def to_dict(self) -> dict:
        """Settings as a plain mapping; `realism` only when one of its effects is on, so an all-off
        profile records the same settings as none."""
        d = asdict(self)
        if self.realism is None or not self.realism.active:
            d.pop("realism")
        return d


def beam_angles(sensor: SensorConfig) -> np.ndarray:
    """Across-track beam angles (rad, (n_beams,)), port to starboard, for the sensor's spacing mode."""
    half = np.deg2rad(0.5 * sensor.swath_deg)
    if sensor.n_beams == 1:
        return np.zeros(1)
    if sensor.spacing == "equiangular":
        return np.linspace(-half, half, sensor.n_beams)
    return np.arctan(np.linspace(-np.tan(half), np.tan(half), sensor.n_beams))


def ping_rate_hz(sensor: SensorConfig, altitude_m: float) -> float:
    """Ping rate (Hz): the sonar's maximum, or less when the two-way travel time to the outer beam's
    seabed return (flat seabed altitude_m below the transducer) is longer than the ping period."""
    if altitude_m <= 0:
        raise ValueError(f"altitude above the seabed must be > 0 m, got {altitude_m}")
    max_range = altitude_m / np.cos(np.deg2rad(0.5 * sensor.swath_deg))
    return float(min(sensor.max_ping_rate_hz, sensor.sound_speed_mps / (2.0 * max_range)))


def swath_half_width_m(sensor: SensorConfig, altitude_m: float) -> float:
    """Across-track half width (m) of the swath on a flat seabed altitude_m below the transducer."""
    return float(altitude_m * np.tan(np.deg2rad(0.5 * sensor.swath_deg)))


@dataclass
class Trajectory:
    """Transducer poses, one per ping: position (P,3) m, heading (P,) rad (direction of travel,
    counter-clockwise from +x), survey line index (P,)."""

    position: np.ndarray
    heading_rad: np.ndarray
    line: np.ndarray

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64).reshape(-1, 3)
        self.heading_rad = np.asarray(self.heading_rad, dtype=np.float64).reshape(-1)
        self.line = np.asarray(self.line, dtype=np.int32).reshape(-1)
        if not (len(self.position) == len(self.heading_rad) == len(self.line)):
            raise ValueError("trajectory arrays must have one entry per ping")

    def __len__(self) -> int:
        return len(self.position)

    @staticmethod
    def concatenate(parts: list["Trajectory"]) -> "Trajectory":
        return Trajectory(
            np.concatenate([p.position for p in parts]) if parts else np.zeros((0, 3)),
            np.concatenate([p.heading_rad for p in parts]) if parts else np.zeros(0),
            np.concatenate([p.line for p in parts]) if parts else np.zeros(0, np.int32),
        )


def straight_line(start_xy, end_xy, z_m: float, sensor: SensorConfig, altitude_m: float, line: int = 0) -> Trajectory:
    """Pings along a straight line from start_xy to end_xy at height z_m, spaced by speed / ping rate."""
    start = np.asarray(start_xy, dtype=np.float64)
    end = np.asarray(end_xy, dtype=np.float64)
    length = float(np.linalg.norm(end - start))
    if length <= 0:
        raise ValueError("a survey line needs distinct start and end points")
    step = sensor.speed_mps / ping_rate_hz(sensor, altitude_m)
    n = int(np.floor(length / step)) + 1
    s = np.arange(n) * step
    d = (end - start) / length
    xy = start + s[:, None] * d
    pos = np.c_[xy, np.full(n, z_m)]
    return Trajectory(pos, np.full(n, np.arctan2(d[1], d[0])), np.full(n, line))


def survey_lines(extent_xy, direction: str, z_m: float, altitude_m: float, overlap: float,
                 sensor: SensorConfig, run_in_m: float = 0.0, first_line: int = 0) -> Trajectory:
    """Parallel survey lines covering the rectangle extent_xy = (xmin, xmax, ymin, ymax).

    direction 'x' runs lines along x (east-west), 'y' along y, 'xy' both sets. Line spacing is the
    flat-seabed swath width times (1 - overlap); lines alternate direction as a vessel would, and
    extend run_in_m beyond the rectangle so its edges get full along-track coverage.
    """
    if direction not in ("x", "y", "xy"):
        raise ValueError(f"survey direction must be 'x', 'y' or 'xy', got {direction!r}")
    if not 0.0 <= overlap < 1.0:
        raise ValueError(f"survey overlap must be in [0, 1), got {overlap}")
    xmin, xmax, ymin, ymax = map(float, extent_xy)
    spacing = 2.0 * swath_half_width_m(sensor, altitude_m) * (1.0 - overlap)
    parts, line = [], first_line
    for axis in ("x", "y") if direction == "xy" else (direction,):
        lo, hi = (ymin, ymax) if axis == "x" else (xmin, xmax)
        n = max(1, int(np.ceil((hi - lo) / spacing)))
        offsets = lo + (hi - lo) / 2.0 + (np.arange(n) - (n - 1) / 2.0) * spacing
        for k, c in enumerate(offsets):
            if axis == "x":
                a, b = (xmin - run_in_m, c), (xmax + run_in_m, c)
            else:
                a, b = (c, ymin - run_in_m), (c, ymax + run_in_m)
            if k % 2:
                a, b = b, a
            parts.append(straight_line(a, b, z_m, sensor, altitude_m, line))
            line += 1
    return Trajectory.concatenate(parts)


class RaycastTarget:
    """Triangle meshes to cast against, each with an integer id reported per sounding.

    meshes: sequence of (vertices (V,3), faces (F,3)) in the scene frame. The Embree BVH is built on
    first use.
    """

    def __init__(self, meshes, ids=None):
        self._scene = o3d.t.geometry.RaycastingScene()
        ids = list(range(len(meshes))) if ids is None else list(ids)
        if len(ids) != len(meshes):
            raise ValueError("one id per mesh is required")
        geometry_to_id = []
        self.n_triangles = 0
        for (v, f), mesh_id in zip(meshes, ids):
            v = np.ascontiguousarray(v, dtype=np.float32)
            f = np.ascontiguousarray(f, dtype=np.uint32)
            if len(f) == 0:
                continue
            gid = self._scene.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(f))
            while len(geometry_to_id) <= gid:
                geometry_to_id.append(NO_HIT)
            geometry_to_id[gid] = mesh_id
            self.n_triangles += len(f)
        # Index INVALID_ID (max uint32) maps to NO_HIT through the last slot of this table.
        self._id_table = np.array(geometry_to_id + [NO_HIT], dtype=np.int32)

    def cast(self, rays: np.ndarray, nthreads: int = 0):
        """Cast rays (R,6) float32 [origin, unit direction]; returns (t_hit (R,), mesh id (R,), normals (R,3)).

        t_hit is inf and the id NO_HIT where nothing is hit.
        """
        rays = np.ascontiguousarray(rays, dtype=np.float32)
        out = self._scene.cast_rays(o3d.core.Tensor.from_numpy(rays), nthreads=nthreads)
        t = out["t_hit"].numpy()
        gid = out["geometry_ids"].numpy().astype(np.int64)
        gid = np.where(gid >= len(self._id_table) - 1, len(self._id_table) - 1, gid)
        return t, self._id_table[gid], out["primitive_normals"].numpy()


def _fan_geometry(trajectory: Trajectory, angles: np.ndarray):
    """Per-ping starboard unit vectors (P,2) and per-beam sin/cos (B,) of the beam angles."""
    h = trajectory.heading_rad
    # Starboard unit vector of each ping: travel direction turned clockwise by 90 degrees.
    stbd = np.stack([np.sin(h), -np.cos(h)], 1)
    return stbd, np.sin(angles), np.cos(angles)


def build_rays(trajectory: Trajectory, angles: np.ndarray) -> np.ndarray:
    """Rays (P*B, 6) float32 [origin, unit direction] for every ping and beam angle, ping-major."""
    stbd, sa, ca = _fan_geometry(trajectory, angles)
    p, b = len(trajectory), len(angles)
    # One broadcast add writes the array once: per-ping part (origin, starboard x/y) times per-beam part.
    per_ping = np.zeros((p, 1, 6), dtype=np.float32)
    per_ping[:, 0, 0:3] = trajectory.position
    if np.all(stbd == stbd[0]):
        per_beam = np.zeros((1, b, 6), dtype=np.float32)
        per_beam[0, :, 3] = stbd[0, 0] * sa
        per_beam[0, :, 4] = stbd[0, 1] * sa
        per_beam[0, :, 5] = -ca
        return (per_ping + per_beam).reshape(p * b, 6)
    rays = np.empty((p, b, 6), dtype=np.float32)
    rays[:, :, 0:3] = trajectory.position[:, None, :]
    rays[:, :, 3] = stbd[:, None, 0] * sa[None, :]
    rays[:, :, 4] = stbd[:, None, 1] * sa[None, :]
    rays[:, :, 5] = -ca[None, :]
    return rays.reshape(p * b, 6)


@dataclass
class Soundings:
    """Ray-cast soundings: positions (M,3) float64 in the scene frame, per-sounding ping, beam, line
    index and id of the mesh hit, and counts of the rays cast and of beams without return."""

    xyz: np.ndarray
    ping: np.ndarray
    beam: np.ndarray
    line: np.ndarray
    mesh: np.ndarray
    n_rays: int = 0
    n_dropped: int = 0

    @staticmethod
    def concatenate(parts: list["Soundings"]) -> "Soundings":
        return Soundings(
            np.concatenate([p.xyz for p in parts]) if parts else np.zeros((0, 3)),
            np.concatenate([p.ping for p in parts]) if parts else np.zeros(0, np.int32),
            np.concatenate([p.beam for p in parts]) if parts else np.zeros(0, np.int16),
            np.concatenate([p.line for p in parts]) if parts else np.zeros(0, np.int16),
            np.concatenate([p.mesh for p in parts]) if parts else np.zeros(0, np.int32),
            sum(p.n_rays for p in parts),
            sum(p.n_dropped for p in parts),
        )


def scan(target: RaycastTarget, trajectory: Trajectory, sensor: SensorConfig, rng: np.random.Generator,
         beams: np.ndarray | None = None, ping_offset: int = 0, chunk_rays: int = 1 << 20,
         nthreads: int = 0) -> Soundings:
    """Simulate the soundings of every ping of `trajectory` against `target`.

    Per beam: an Embree ray cast from the transducer; beams that hit nothing, random dropouts
    (sensor.dropout_prob) and grazing-angle dropouts (probability rising quadratically from 0 at
    sensor.grazing_start_deg incidence to sensor.grazing_dropout_prob at 90 deg) give no sounding;
    the others get Gaussian range noise N(0, range_sigma_m^2) along the beam. `beams` optionally
    restricts the cast to a subset of beam indices (the others are not modelled at all). Ping
    indices in the output start at ping_offset. Output order is ping-major, beam-minor.

    With `sensor.realism` holding an effect that is on, the effects of
    :mod:`sonardet.sim.realism` apply as well (then n_rays counts every sub-ray cast); otherwise
    the output is that of the plain ray cast, bytes included.
    """
    angles_all = beam_angles(sensor)
    beam_idx = np.arange(sensor.n_beams) if beams is None else np.asarray(beams, dtype=np.int64)
    angles = angles_all[beam_idx]
    nb = len(angles)
    if len(trajectory) == 0 or nb == 0:
        return Soundings(np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros(0, np.int16),
                         np.zeros(0, np.int16), np.zeros(0, np.int32))
    if sensor.realism is not None and sensor.realism.active:
        return _scan_realistic(target, trajectory, sensor, rng, beam_idx, angles_all, ping_offset, chunk_rays,
                               nthreads)
    cos_start = np.float32(np.cos(np.deg2rad(sensor.grazing_start_deg)))
    pings_per_chunk = max(1, chunk_rays // nb)
    parts = []
    for p0 in range(0, len(trajectory), pings_per_chunk):
        sl = slice(p0, p0 + pings_per_chunk)
        traj = Trajectory(trajectory.position[sl], trajectory.heading_rad[sl], trajectory.line[sl])
        npg = len(traj)
        t, mesh_id, normals = target.cast(build_rays(traj, angles), nthreads)
        # Work on the (ping, beam) grid with broadcasting: no per-ray gathers until the final compress.
        stbd, sa, ca = _fan_geometry(traj, angles)
        t = t.reshape(npg, nb)
        hit = np.isfinite(t)
        keep = hit.copy()
        p_drop = np.full((npg, nb), np.float32(sensor.dropout_prob), dtype=np.float32)
        if sensor.grazing_dropout_prob > 0 and cos_start > 0:
            n = normals.reshape(npg, nb, 3)
            dx = (stbd[:, 0:1] * sa[None, :]).astype(np.float32)
            dy = (stbd[:, 1:2] * sa[None, :]).astype(np.float32)
            cos_inc = np.abs(dx * n[:, :, 0] + dy * n[:, :, 1] - ca.astype(np.float32)[None, :] * n[:, :, 2])
            u = np.clip((cos_start - cos_inc) / cos_start, 0.0, 1.0)
            p_drop += np.float32(sensor.grazing_dropout_prob) * u * u
        if np.any(p_drop > 0):
            keep &= rng.random((npg, nb), dtype=np.float32) >= p_drop
        r = t
        if sensor.range_sigma_m > 0:
            r = t + np.float32(sensor.range_sigma_m) * rng.standard_normal((npg, nb), dtype=np.float32)
        # Soundings on the full grid in float64 (contiguous, vectorised), then one boolean compress.
        # Missed beams (t = inf) give inf/nan there, which the compress drops.
        with np.errstate(invalid="ignore"):
            sr = sa[None, :] * r
            xyz = np.stack([
                (traj.position[:, 0:1] + stbd[:, 0:1] * sr)[keep],
                (traj.position[:, 1:2] + stbd[:, 1:2] * sr)[keep],
                (traj.position[:, 2:3] - ca[None, :] * r)[keep],
            ], 1)
        ping = np.broadcast_to(np.arange(p0 + ping_offset, p0 + ping_offset + npg, dtype=np.int32)[:, None],
                               (npg, nb))[keep]
        parts.append(Soundings(
            xyz=xyz,
            ping=ping,
            beam=np.broadcast_to(beam_idx.astype(np.int16)[None, :], (npg, nb))[keep],
            line=np.broadcast_to(traj.line.astype(np.int16)[:, None], (npg, nb))[keep],
            mesh=mesh_id.reshape(npg, nb)[keep],
            n_rays=npg * nb,
            n_dropped=int(hit.sum() - len(xyz)),
        ))
    return Soundings.concatenate(parts)


def _scan_realistic(target: RaycastTarget, trajectory: Trajectory, sensor: SensorConfig, rng: np.random.Generator,
                    beam_idx: np.ndarray, angles_all: np.ndarray, ping_offset: int, chunk_rays: int,
                    nthreads: int) -> Soundings:
    """:func:`scan` with the realism profile `sensor.realism`; the models and their order are those
    of :mod:`sonardet.sim.realism`. The sensor's own dropouts and range noise draw from `rng` exactly
    as the plain scan does; the realism effects draw from a spawned child of it."""
    rz = sensor.realism
    rrng = rlz.child_rng(rng)
    angles = angles_all[beam_idx]
    nb = len(angles)
    half = np.deg2rad(0.5 * sensor.swath_deg)

    # Per-ping attitude: true (rays) and as the georeferencing knows it.
    lp = rlz.draw_line_params(rz, trajectory.line, rrng)
    li = lp.index(trajectory.line)
    t_s = rlz.ping_times_s(trajectory.position, trajectory.line, sensor.speed_mps)
    roll_m, pitch_m, yaw_m, heave_m = rlz.motion(rz, t_s, lp.phase[li])
    roll_true, pitch_true = lp.roll_bias[li] + roll_m, lp.pitch_bias[li] + pitch_m
    moves = rz.motion_compensated and any(np.any(a != 0) for a in (roll_m, pitch_m, yaw_m, heave_m))
    across_true = rlz.steered_angles(angles, rz, sensor.sound_speed_mps)

    d_across, d_along, weight = rlz.subray_bundle(rz)
    ns = len(weight)
    if rz.detection == "auto":
        phase_beam = np.abs(angles) > np.deg2rad(rz.detection_switch_deg)
    else:
        phase_beam = np.full(nb, rz.detection == "phase")
    p_outer = rlz.outer_dropout_probability(rz, angles, half).astype(np.float32)
    p_spike = rlz.outlier_probability(rz, angles, angles_all, half)
    cos_start = np.float32(np.cos(np.deg2rad(sensor.grazing_start_deg)))
    any_svp = np.any(lp.svp_k != 0)

    pings_per_chunk = max(1, chunk_rays // (nb * ns))
    parts = []
    for p0 in range(0, len(trajectory), pings_per_chunk):
        sl = slice(p0, p0 + pings_per_chunk)
        pos = trajectory.position[sl]
        heading = trajectory.heading_rad[sl]
        lines = trajectory.line[sl]
        npg = len(pos)
        per_ping = (slice(None), None, None)
        dirs = rlz.fan_directions((heading + yaw_m[sl])[per_ping], roll_true[sl][per_ping],
                                  pitch_true[sl][per_ping], across_true[None, :, None] + d_across[None, None, :],
                                  d_along[None, None, :])
        rays = np.empty((npg, nb, ns, 6), dtype=np.float32)
        rays[..., 0:3] = (pos + np.c_[np.zeros((npg, 2)), heave_m[sl]])[:, None, None, :]
        rays[..., 3:6] = dirs
        t, mesh_sub, normals = target.cast(rays.reshape(-1, 6), nthreads)
        t = t.reshape(npg, nb, ns).astype(np.float64)
        mesh_sub = mesh_sub.reshape(npg, nb, ns)
        cos_inc = np.abs(np.einsum("pbsk,pbsk->pbs", dirs, normals.reshape(npg, nb, ns, 3)))
        if rz.object_roughness_sigma_m > 0:
            t = t + rlz.roughness_range_offsets(t, mesh_sub, cos_inc, rz.object_roughness_sigma_m, rrng)
        r, pick, hit = rlz.combine_subrays(t, weight, phase_beam, first=rz.detection == "first")
        mesh_id = np.take_along_axis(mesh_sub, pick[..., None], 2)[..., 0]

        keep = hit.copy()
        p_drop = np.full((npg, nb), np.float32(sensor.dropout_prob), dtype=np.float32)
        if sensor.grazing_dropout_prob > 0 and cos_start > 0:
            c = np.take_along_axis(cos_inc, pick[..., None], 2)[..., 0].astype(np.float32)
            u = np.clip((cos_start - c) / cos_start, 0.0, 1.0)
            p_drop += np.float32(sensor.grazing_dropout_prob) * u * u
        p_drop += p_outer[None, :]
        if np.any(p_drop > 0):
            keep &= rng.random((npg, nb), dtype=np.float32) >= p_drop
        if sensor.range_sigma_m > 0:
            r = r + np.float32(sensor.range_sigma_m) * rng.standard_normal((npg, nb), dtype=np.float32)
        if rz.outlier_prob > 0:
            r = np.maximum(r + rlz.outlier_offsets((npg, nb), p_spike, rz.outlier_magnitude_m, rrng), 0.0)
        r = rlz.quantise(r, rz.range_quantum_m)

        # Georeferencing with the attitude the processing knows (nominal, or with the motion).
        if moves:
            geo_dir = rlz.fan_directions((heading + yaw_m[sl])[:, None], roll_m[sl][:, None], pitch_m[sl][:, None],
                                         angles[None, :], 0.0)
            geo_origin = pos + np.c_[np.zeros((npg, 2)), heave_m[sl]]
        else:
            stbd, sa, ca = _fan_geometry(Trajectory(pos, heading, lines), angles)
            geo_dir = np.stack(np.broadcast_arrays(stbd[:, 0:1] * sa[None, :], stbd[:, 1:2] * sa[None, :],
                                                   -ca[None, :]), axis=-1)
            geo_origin = pos
        with np.errstate(invalid="ignore"):
            xyz = geo_origin[:, None, :] + r[..., None] * geo_dir
            lj = li[sl]
            dz = np.broadcast_to(lp.offset_m[lj][:, None], (npg, nb))
            if any_svp:
                cos_v = -geo_dir[..., 2]
                dz = dz + rlz.svp_bias_dz(lp.svp_k[lj][:, None], r * cos_v, cos_v)
            xyz[..., 2] += dz
        ping = np.broadcast_to(np.arange(p0 + ping_offset, p0 + ping_offset + npg, dtype=np.int32)[:, None],
                               (npg, nb))[keep]
        parts.append(Soundings(
            xyz=xyz[keep],
            ping=ping,
            beam=np.broadcast_to(beam_idx.astype(np.int16)[None, :], (npg, nb))[keep],
            line=np.broadcast_to(lines.astype(np.int16)[:, None], (npg, nb))[keep],
            mesh=mesh_id[keep],
            n_rays=npg * nb * ns,
            n_dropped=int(hit.sum() - keep.sum()),
        ))
    return Soundings.concatenate(parts)
