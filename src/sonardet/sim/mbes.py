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

from .effects import (
    RealismConfig,
    ScanChunk,
    ScanSetup,
    child_rng,
    draw_lines,
    fan_directions,
    ping_times_s,
    pipeline,
)
from .effects.footprint import combine_subrays
from .effects.noise import range_noise

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
        mapping becomes a :class:`~sonardet.sim.effects.RealismConfig`."""
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


def sounding_spacing_m(sensor: SensorConfig, altitude_m: float, overlap: float) -> tuple[float, float]:
    """Mean spacing (m) of the soundings on a flat seabed `altitude_m` below the transducer: (across
    track: the swath width over the gaps between its beams, or, for a single beam, the line spacing of
    `survey_lines` with the swath `overlap` (share); along track: speed / ping rate)."""
    width = 2.0 * swath_half_width_m(sensor, altitude_m)
    across = width * (1.0 - overlap) if sensor.n_beams == 1 else width / (sensor.n_beams - 1)
    return float(across), float(sensor.speed_mps / ping_rate_hz(sensor, altitude_m))


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


def survey_lines_per_direction(sensor: SensorConfig, altitude_m: float, overlap: float, extent_m) -> int:
    """Most survey lines `survey_lines` runs in one direction over a scene of `extent_m` (x, y sizes, m)."""
    spacing = 2.0 * swath_half_width_m(sensor, altitude_m) * (1.0 - overlap)
    return max(1, int(np.ceil(max(float(e) for e in extent_m) / spacing)))


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
        gid = np.minimum(out["geometry_ids"].numpy(), np.uint32(len(self._id_table) - 1))
        return t, self._id_table.take(gid), out["primitive_normals"].numpy()


def _starboard(heading_rad: np.ndarray) -> np.ndarray:
    """Starboard unit vectors (P,2) of pings with headings (P,) rad: travel direction turned
    clockwise by 90 degrees."""
    return np.stack([np.sin(heading_rad), -np.cos(heading_rad)], 1)


def _fan_geometry(trajectory: Trajectory, angles: np.ndarray):
    """Per-ping starboard unit vectors (P,2) and per-beam sin/cos (B,) of the beam angles."""
    return _starboard(trajectory.heading_rad), np.sin(angles), np.cos(angles)


def build_rays(trajectory: Trajectory, angles: np.ndarray) -> np.ndarray:
    """Rays (P*B, 6) float32 [origin, unit direction] for every ping and beam angle, ping-major."""
    stbd, sa, ca = _fan_geometry(trajectory, angles)
    return _fan_rays(trajectory.position, stbd, sa, ca, bool(np.all(stbd == stbd[0])))


def _fan_rays(position: np.ndarray, stbd: np.ndarray, sa: np.ndarray, ca: np.ndarray,
              same_heading: bool) -> np.ndarray:
    """Rays (P*B, 6) float32 of pings at position (P,3) m with starboard unit vectors stbd (P,2) and
    beam sin/cos sa, ca (B,) (see :func:`_fan_geometry`). same_heading: every row of stbd equals the
    first; :func:`scan` decides it per chunk, so a chunk's rays have the same bytes in any split."""
    p, b = len(position), len(sa)
    if same_heading:
        # Per-ping origin plus per-beam direction, each + 0.0f as the sum of the two zero-padded parts
        # always was (it turns -0.0 into +0.0); one row of directions is copied to every ping.
        per_beam = np.zeros((b, 6), dtype=np.float32)
        per_beam[:, 3] = stbd[0, 0] * sa
        per_beam[:, 4] = stbd[0, 1] * sa
        per_beam[:, 5] = -ca
        per_beam += np.float32(0.0)
        origin = position.astype(np.float32) + np.float32(0.0)
        rays = np.empty((p, b, 6), dtype=np.float32)
        rays[:] = per_beam
        for k in range(3):
            rays[:, :, k] = origin[:, k:k + 1]
        return rays.reshape(p * b, 6)
    rays = np.empty((p, b, 6), dtype=np.float32)
    rays[:, :, 0:3] = position[:, None, :]
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
         nthreads: int = 0, slab_rays: int = 1 << 15) -> Soundings:
    """Simulate the soundings of every ping of `trajectory` against `target`.

    Per beam: an Embree ray cast from the transducer; beams that hit nothing, random dropouts
    (sensor.dropout_prob) and grazing-angle dropouts (probability rising quadratically from 0 at
    sensor.grazing_start_deg incidence to sensor.grazing_dropout_prob at 90 deg) give no sounding;
    the others get Gaussian range noise N(0, range_sigma_m^2) along the beam. `beams` optionally
    restricts the cast to a subset of beam indices (the others are not modelled at all). Ping
    indices in the output start at ping_offset. Output order is ping-major, beam-minor.

    The random draws are made per chunk of about chunk_rays rays (whole pings), so chunk_rays is
    part of what defines the output, as the seed is. The plain cast works through each chunk in slabs
    of about slab_rays rays (whole pings; small enough for the CPU caches); slab_rays changes the
    speed only, never a byte.

    With `sensor.realism` holding an effect that is on, the sensor effects of
    :mod:`sonardet.sim.effects` apply as well (then n_rays counts every sub-ray cast); otherwise
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
    per_chunk = max(1, chunk_rays // nb)
    per_slab = min(per_chunk, max(1, slab_rays // nb))
    plain = _PlainScan(target, trajectory, sensor, rng, beam_idx, angles, ping_offset, per_slab, nthreads)
    # One thread, slab after slab: Open3D's cast_rays holds the GIL (0.20), so a worker thread casting
    # the next slab would not overlap the numpy work on this one (measured: no gain).
    for c0 in range(0, len(trajectory), per_chunk):
        plain.chunk(c0, min(c0 + per_chunk, len(trajectory)))
    return plain.out.soundings()


class _PlainScan:
    """The plain ray cast of :func:`scan` (no realism effect on): its constants, output buffer and the
    work per chunk of pings (random draws) and per slab (ray cast)."""

    def __init__(self, target: RaycastTarget, trajectory: Trajectory, sensor: SensorConfig,
                 rng: np.random.Generator, beam_idx: np.ndarray, angles: np.ndarray, ping_offset: int,
                 per_slab: int, nthreads: int):
        self.target, self.rng, self.nthreads, self.ping_offset = target, rng, nthreads, ping_offset
        self.cos_start = np.float32(np.cos(np.deg2rad(sensor.grazing_start_deg)))
        self.grazing = sensor.grazing_dropout_prob > 0 and self.cos_start > 0
        self.p_base, self.p_grazing = np.float32(sensor.dropout_prob), np.float32(sensor.grazing_dropout_prob)
        self.sigma = np.float32(sensor.range_sigma_m)
        self.noisy = sensor.range_sigma_m > 0
        self.pos, self.line16 = trajectory.position, trajectory.line.astype(np.int16)
        self.heading = trajectory.heading_rad
        self.sa, self.ca = np.sin(angles), np.cos(angles)
        self.nb = len(angles)
        self.per_slab = per_slab
        self.beam_grid = np.broadcast_to(beam_idx.astype(np.int16), (per_slab, self.nb)).ravel()
        self.out = _SoundingBuffer(len(trajectory) * self.nb)

    def chunk(self, c0: int, c1: int) -> None:
        """Cast, draw for and emit pings c0:c1 (one chunk: one set of random draws)."""
        nb = self.nb
        stbd = _starboard(self.heading[c0:c1])
        same_heading = bool(np.all(stbd == stbd[0]))
        # The chunk draws its dropout uniforms only if some beam has a dropout probability > 0; with
        # grazing dropouts that is known once a slab shows one, else after the chunk's last slab.
        draw_u = None if self.grazing else bool(self.p_base > 0)
        drawn, u_drop, noise = False, None, None
        waiting = []
        for s0 in range(c0, c1, self.per_slab):
            s1 = min(s0 + self.per_slab, c1)
            n = s1 - s0
            rays = _fan_rays(self.pos[s0:s1], stbd[s0 - c0:s1 - c0], self.sa, self.ca, same_heading)
            t, mesh_id, normals = self.target.cast(rays, self.nthreads)
            p_drop = self.p_base
            if self.grazing:
                p_drop = self._grazing_dropout(rays, normals, n, same_heading)
                if draw_u is None and np.any(p_drop > 0):
                    draw_u = True
            waiting.append((s0, s1, t.reshape(n, nb), mesh_id.reshape(n, nb), p_drop))
            if draw_u is None and s1 < c1:
                continue
            if not drawn:
                if draw_u:
                    u_drop = self.rng.random((c1 - c0, nb), dtype=np.float32)
                if self.noisy:
                    noise = self.rng.standard_normal((c1 - c0, nb), dtype=np.float32)
                drawn = True
            for w0, w1, t, mesh_id, p_drop in waiting:
                rows = slice(w0 - c0, w1 - c0)
                self.emit(w0, w1, stbd[rows], t, mesh_id, p_drop, None if u_drop is None else u_drop[rows],
                          None if noise is None else noise[rows])
            waiting.clear()

    def _grazing_dropout(self, rays: np.ndarray, normals: np.ndarray, n: int, same_heading: bool) -> np.ndarray:
        """Dropout probability (n, B) float32 of a slab's beams: random plus grazing-angle dropouts."""
        # Incidence from the float32 directions of the rays: the same bytes as float32(stbd * sin)
        # and -float32(cos); one row of them serves every ping of a same-heading chunk.
        d = rays.reshape(n, self.nb, 6)[:1 if same_heading else n, :, 3:6]
        nrm = normals.reshape(n, self.nb, 3)
        c = d[..., 0] * nrm[..., 0]
        c += d[..., 1] * nrm[..., 1]
        c += d[..., 2] * nrm[..., 2]
        np.abs(c, out=c)
        u = np.clip((self.cos_start - c) / self.cos_start, 0.0, 1.0)
        return self.p_base + self.p_grazing * u * u

    def emit(self, s0, s1, stbd, t, mesh_id, p_drop, u_drop, noise) -> None:
        """Soundings of pings s0:s1 (stbd (n,2), t, mesh_id (n,B); u_drop, noise: their rows of the
        chunk's draws or None)."""
        pos, sa, ca, out = self.pos, self.sa, self.ca, self.out
        hit = np.isfinite(t)
        keep = hit if u_drop is None else hit & (u_drop >= p_drop)
        r = t if noise is None else t + self.sigma * noise
        idx = np.flatnonzero(keep)
        counts = keep.sum(1)
        xyz = out.xyz(len(idx))
        # Soundings on the slab's grid in float64, then gathered. Missed beams (t = inf) give inf/nan
        # there, which the gather skips.
        with np.errstate(invalid="ignore"):
            sr = sa * r
            for k in range(2):
                xyz[:, k] = (pos[s0:s1, k:k + 1] + stbd[:, k:k + 1] * sr).ravel().take(idx)
            xyz[:, 2] = (pos[s0:s1, 2:3] - ca * r).ravel().take(idx)
        po = self.ping_offset
        out.add(ping=np.repeat(np.arange(s0 + po, s1 + po, dtype=np.int32), counts),
                beam=self.beam_grid.take(idx), line=np.repeat(self.line16[s0:s1], counts),
                mesh=mesh_id.ravel().take(idx), n_rays=t.size, n_dropped=np.count_nonzero(hit) - len(idx))


class _SoundingBuffer:
    """Soundings appended slab by slab into arrays sized for every ray cast (pages never written are
    never committed), handed out trimmed: no concatenation copy at the end."""

    def __init__(self, n_max: int):
        self._xyz = np.empty((n_max, 3))
        self._ping = np.empty(n_max, np.int32)
        self._beam = np.empty(n_max, np.int16)
        self._line = np.empty(n_max, np.int16)
        self._mesh = np.empty(n_max, np.int32)
        self.n = self.n_rays = self.n_dropped = 0

    def xyz(self, m: int) -> np.ndarray:
        """The next m rows of positions, to be written before :meth:`add` commits them."""
        return self._xyz[self.n:self.n + m]

    def add(self, ping, beam, line, mesh, n_rays: int, n_dropped: int):
        m = len(ping)
        for dst, src in ((self._ping, ping), (self._beam, beam), (self._line, line), (self._mesh, mesh)):
            dst[self.n:self.n + m] = src
        self.n += m
        self.n_rays += n_rays
        self.n_dropped += n_dropped

    def soundings(self) -> Soundings:
        n = self.n
        return Soundings(self._xyz[:n], self._ping[:n], self._beam[:n], self._line[:n], self._mesh[:n],
                         self.n_rays, self.n_dropped)


def _scan_realistic(target: RaycastTarget, trajectory: Trajectory, sensor: SensorConfig, rng: np.random.Generator,
                    beam_idx: np.ndarray, angles_all: np.ndarray, ping_offset: int, chunk_rays: int,
                    nthreads: int) -> Soundings:
    """:func:`scan` with the realism profile `sensor.realism`: the registered sensor effects set the
    scan up (:func:`_realism_setup`), then act on each chunk of pings stage by stage (ray, range,
    sounding, point; :mod:`sonardet.sim.effects`). The sensor's own dropouts and range noise draw
    from `rng` exactly as the plain scan does; the effects draw from a spawned child of it."""
    rz = sensor.realism
    rrng = child_rng(rng)
    setup = _realism_setup(rz, trajectory, sensor, beam_idx, angles_all, rrng)
    stages = {stage: [e for e in pipeline(stage) if e.apply is not None and e.on(rz)]
              for stage in ("range", "sounding", "point")}
    ns = len(setup.sub_weight)
    nb = len(beam_idx)
    pings_per_chunk = max(1, chunk_rays // (nb * ns))
    parts = []
    for p0 in range(0, len(trajectory), pings_per_chunk):
        sl = slice(p0, p0 + pings_per_chunk)
        chunk = ScanChunk(sl, trajectory.position[sl], trajectory.heading_rad[sl], setup.line_index[sl])
        _cast_chunk(target, setup, chunk, nthreads)
        for e in stages["range"]:
            e.apply(rz, setup, chunk, rrng)
        mesh_id, hit = _detect_chunk(sensor, setup, chunk, rng)
        for e in stages["sounding"]:
            e.apply(rz, setup, chunk, rrng)
        xyz = _georeference_chunk(setup, chunk, stages["point"], rz, rrng)
        keep, npg = chunk.keep, len(chunk.position)
        ping = np.broadcast_to(np.arange(p0 + ping_offset, p0 + ping_offset + npg, dtype=np.int32)[:, None],
                               (npg, nb))[keep]
        parts.append(Soundings(
            xyz=xyz[keep],
            ping=ping,
            beam=np.broadcast_to(beam_idx.astype(np.int16)[None, :], (npg, nb))[keep],
            line=np.broadcast_to(trajectory.line[sl].astype(np.int16)[:, None], (npg, nb))[keep],
            mesh=mesh_id[keep],
            n_rays=npg * nb * ns,
            n_dropped=int(hit.sum() - keep.sum()),
        ))
    return Soundings.concatenate(parts)


def _realism_setup(rz: RealismConfig, trajectory: Trajectory, sensor: SensorConfig, beam_idx: np.ndarray,
                   angles_all: np.ndarray, rrng: np.random.Generator) -> ScanSetup:
    """The per-line draws (from rrng, always the same ones) and every sensor effect's setup, in
    pipeline order: the true and known attitude per ping, beam steering, sub-ray bundle, detection,
    extra dropout probabilities (:class:`~sonardet.sim.effects.ScanSetup`)."""
    lines = draw_lines(trajectory.line, rrng)
    setup = ScanSetup(angles_rad=angles_all[beam_idx], all_angles_rad=angles_all,
                      half_swath_rad=np.deg2rad(0.5 * sensor.swath_deg), sound_speed_mps=sensor.sound_speed_mps,
                      lines=lines, line_index=lines.index(trajectory.line),
                      t_s=ping_times_s(trajectory.position, trajectory.line, sensor.speed_mps))
    for stage in ("ray", "range", "sounding", "point"):
        for e in pipeline(stage):
            if e.setup is not None:
                e.setup(rz, setup)
    return setup


def _cast_chunk(target: RaycastTarget, setup: ScanSetup, chunk: ScanChunk, nthreads: int) -> None:
    """Ray stage of one chunk: cast every sub-ray with the true attitude, heave and steering; sets
    chunk.dirs, t (float64), mesh and cos_incidence."""
    sl, pos, heading = chunk.pings, chunk.position, chunk.heading_rad
    npg, nb, ns = len(pos), len(setup.angles_rad), len(setup.sub_weight)
    per_ping = (slice(None), None, None)
    dirs = fan_directions((heading + setup.yaw_rad[sl])[per_ping], setup.roll_rad[sl][per_ping],
                          setup.pitch_rad[sl][per_ping],
                          setup.across_rad[None, :, None] + setup.sub_across_rad[None, None, :],
                          setup.sub_along_rad[None, None, :])
    rays = np.empty((npg, nb, ns, 6), dtype=np.float32)
    rays[..., 0:3] = (pos + np.c_[np.zeros((npg, 2)), setup.heave_m[sl]])[:, None, None, :]
    rays[..., 3:6] = dirs
    t, mesh_sub, normals = target.cast(rays.reshape(-1, 6), nthreads)
    chunk.dirs = dirs
    chunk.t = t.reshape(npg, nb, ns).astype(np.float64)
    chunk.mesh = mesh_sub.reshape(npg, nb, ns)
    chunk.cos_incidence = np.abs(np.einsum("pbsk,pbsk->pbs", dirs, normals.reshape(npg, nb, ns, 3)))


def _detect_chunk(sensor: SensorConfig, setup: ScanSetup, chunk: ScanChunk, rng: np.random.Generator):
    """Detection and the sensor's own dropouts and range noise of one chunk: combine the sub-rays
    (footprint), drop beams (random, grazing and the effects' extra dropouts; one draw from `rng`),
    add the range noise (from `rng`). Sets chunk.r and chunk.keep; returns (mesh id (n, B), hit
    (n, B): detected before the dropouts)."""
    r, pick, hit = combine_subrays(chunk.t, setup.sub_weight, setup.phase_beam, first=setup.first)
    mesh_id = np.take_along_axis(chunk.mesh, pick[..., None], 2)[..., 0]
    npg, nb = r.shape
    keep = hit.copy()
    p_drop = np.full((npg, nb), np.float32(sensor.dropout_prob), dtype=np.float32)
    cos_start = np.float32(np.cos(np.deg2rad(sensor.grazing_start_deg)))
    if sensor.grazing_dropout_prob > 0 and cos_start > 0:
        c = np.take_along_axis(chunk.cos_incidence, pick[..., None], 2)[..., 0].astype(np.float32)
        u = np.clip((cos_start - c) / cos_start, 0.0, 1.0)
        p_drop += np.float32(sensor.grazing_dropout_prob) * u * u
    if setup.extra_dropout_prob is not None:
        p_drop += setup.extra_dropout_prob[None, :]
    if np.any(p_drop > 0):
        keep &= rng.random((npg, nb), dtype=np.float32) >= p_drop
    if sensor.range_sigma_m > 0:
        r = r + range_noise((npg, nb), sensor.range_sigma_m, rng)
    chunk.r, chunk.keep = r, keep
    return mesh_id, hit


def _georeference_chunk(setup: ScanSetup, chunk: ScanChunk, point_effects, rz: RealismConfig,
                        rrng: np.random.Generator) -> np.ndarray:
    """Point stage of one chunk: soundings (n, B, 3) m placed with the attitude the processing knows
    (nominal, or with the motion when it is compensated), then moved by the point-stage effects."""
    sl, pos, heading = chunk.pings, chunk.position, chunk.heading_rad
    angles = setup.angles_rad
    if setup.georef_motion is not None:
        roll, pitch, yaw, heave = setup.georef_motion
        geo_dir = fan_directions((heading + yaw[sl])[:, None], roll[sl][:, None], pitch[sl][:, None],
                                 angles[None, :], 0.0)
        geo_origin = pos + np.c_[np.zeros((len(pos), 2)), heave[sl]]
    else:
        stbd, sa, ca = _starboard(heading), np.sin(angles), np.cos(angles)
        geo_dir = np.stack(np.broadcast_arrays(stbd[:, 0:1] * sa[None, :], stbd[:, 1:2] * sa[None, :],
                                               -ca[None, :]), axis=-1)
        geo_origin = pos
    chunk.geo_dir = geo_dir
    with np.errstate(invalid="ignore"):
        xyz = geo_origin[:, None, :] + chunk.r[..., None] * geo_dir
        for e in point_effects:
            e.apply(rz, setup, chunk, rrng)
        if chunk.dz is not None:
            xyz[..., 2] += chunk.dz
    return xyz
