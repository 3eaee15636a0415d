"""Sensor realism profile: effects of real multibeam data that a plain ray cast misses.

Every effect is off by default; :class:`RealismConfig` (the `sensor.realism` config section) turns
each one on. :func:`sonardet.sim.mbes.scan` applies them; with every effect off it runs its plain
path and gives the same bytes as without a profile.

Frames and units follow :mod:`sonardet.sim.mbes`: scene frame x east, y north, z up, metres,
radians inside the code, degrees only in config names ending `_deg`. The sonar body frame is
x forward, y starboard, z down; roll is positive starboard-down, pitch positive bow-up, yaw positive
counter-clockwise seen from above (the scene's heading convention). A beam's body-frame direction
is (sin b, cos b sin a, cos b cos a) for across-track angle a and along-track angle b; the attitude
rotates it as Ry(pitch) Rx(roll), then the heading maps it into the scene frame.

The effects, in the order the scan applies them:

1. Attitude (rays only): per-line roll and pitch biases (a fixed part plus a random per-line part),
   roll, pitch and yaw sinusoids and heave. The rays leave the transducer with the true attitude and
   position; the soundings are georeferenced with the nominal ones, so a bias shows as a tilt: a
   roll bias phi moves a sounding at across-track distance y on a flat seabed vertically by about
   y tan(phi) (positive roll raises the starboard side). With `motion_compensated` the
   sinusoids and heave are known to the georeferencing and only the biases are errors; the motion
   then only moves where the beams land.
2. Surface sound-speed error (rays only): a flat receive array steers with the sound speed it
   assumes, c_a = c + error, so by Snell's law the true angle obeys sin(a_true) = sin(a) c / c_a
   while the sounding is placed at a. An assumed speed above the true one steers the beams too
   little and the outer beams rise (a smile); below, they sink (a frown). Ranges are unaffected.
3. Beam footprint: each beam is a bundle of sub-rays on a regular grid over its across x along
   beamwidth (the -3 dB full widths), weighted by a Gaussian beam pattern that falls to 1/2 at the
   grid's edge. The beam's range combines the sub-ray ranges: 'amplitude' detection takes their
   weighted mean (rounds edges, fills small holes partly), 'phase' their weighted median (a hole
   with less than half of the beam's weight is not seen), 'first' the shortest (first arrival), and
   'auto' switches from amplitude to phase beyond `detection_switch_deg` like an R2Sonic. A beam
   whose hit sub-rays hold less than half of its weight gives no sounding. The mesh id and normal
   of a beam are those of the sub-ray whose range is nearest the combined one.
4. Object roughness (biofouling), per sub-ray: hits on meshes with id >= 0 (the reef objects in
   scenes and templates; seabed and rocks carry negative ids) move along the ray as if the surface
   were displaced along its normal by N(0, sigma^2), so the distance of such a hit to the mesh has
   RMS about sigma. The displacement is independent from hit to hit (no spatial correlation).
5. Extra dropouts at outer beams: a probability rising quadratically with beam angle from 0 at
   `outer_dropout_start_deg` to `outer_dropout_prob` at the swath edge (added to the sensor's own
   random and grazing dropouts).
6. Outliers: a share `outlier_prob` of the soundings (averaged over the swath's beams) is moved
   along its beam by +-U(0.1, 1) x `outlier_magnitude_m`; the probability per beam grows as
   |angle / half swath| ** `outlier_outer_power`, so spikes concentrate at the outer beams.
7. Range quantisation: reported ranges are rounded to multiples of `range_quantum_m`.
8. Water-column sound-speed (SVP) bias: the sounding's elevation changes by
   k D (1 / cos(a) - 1), with D its depth below the transducer and a its vertical beam angle, so
   k > 0 raises the outer beams (a smile). k is `svp_bias_coeff` plus a random per-line part;
   k = 0.0073 gives 1 % of the depth at 65 deg, the size reported for modelled instead of
   measured profiles.
9. Line-to-line vertical offsets: every sounding of a survey line moves by the line's N(0, sigma^2)
   offset (tide, draft and heave-filter residuals).

The random parts draw from a child generator spawned from the scan's generator, so the sensor's own
dropouts and range noise keep their realisation when effects are turned on or off.

Object burial is a scene property (`scenes.realism.burial_m`): :func:`burial_depths` draws it and
:func:`sonardet.sim.scene.simulate_scene` lowers the settled objects.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

DETECTION_MODES = ("amplitude", "phase", "first", "auto")

#: Smallest |cos(incidence)| used to turn a normal displacement into a range change (about 78 deg),
#: so grazing hits on a rough surface do not jump by metres.
_MIN_COS_INCIDENCE = 0.2


@dataclass(frozen=True)
class RealismConfig:
    """Sensor realism effects (the `sensor.realism` config section); every default turns its effect off.

    Units are in the names: metres (_m), degrees (_deg), seconds (_s), m/s (_mps); counts and
    probabilities are unitless. See the module docstring for the models.
    """

    footprint_n_across: int = 1  # sub-rays across track per beam (1 x 1 = a single ray, off)
    footprint_n_along: int = 1  # sub-rays along track per beam
    beamwidth_across_deg: float = 0.5  # receive beamwidth (-3 dB full width, deg)
    beamwidth_along_deg: float = 1.0  # transmit beamwidth (-3 dB full width, deg)
    detection: str = "amplitude"  # amplitude | phase | first | auto
    detection_switch_deg: float = 30.0  # 'auto': phase detection beyond this |beam angle| (deg)
    range_quantum_m: float = 0.0  # range step (m); 0 = off
    roll_bias_deg: float = 0.0  # roll bias of every line (deg, + starboard down)
    roll_bias_sigma_deg: float = 0.0  # std of an extra random roll bias per line (deg)
    pitch_bias_deg: float = 0.0  # pitch bias of every line (deg, + bow up)
    pitch_bias_sigma_deg: float = 0.0  # std of an extra random pitch bias per line (deg)
    roll_amplitude_deg: float = 0.0  # roll sinusoid amplitude (deg)
    roll_period_s: float = 2.75
    pitch_amplitude_deg: float = 0.0  # pitch sinusoid amplitude (deg)
    pitch_period_s: float = 4.0
    yaw_amplitude_deg: float = 0.0  # yaw wobble amplitude (deg, + counter-clockwise)
    yaw_period_s: float = 10.0
    heave_amplitude_m: float = 0.0  # heave sinusoid amplitude (m, + up)
    heave_period_s: float = 6.0
    motion_compensated: bool = False  # sinusoids and heave known to the georeferencing
    surface_sound_speed_error_mps: float = 0.0  # assumed minus true sound speed at the array (m/s)
    svp_bias_coeff: float = 0.0  # k of the SVP bias k D (1/cos a - 1), + raises outer beams
    svp_bias_sigma: float = 0.0  # std of an extra random k per line
    outlier_prob: float = 0.0  # share of soundings that are spikes (mean over the swath)
    outlier_magnitude_m: float = 0.5  # largest spike displacement along the beam (m)
    outlier_outer_power: float = 2.0  # spike probability grows as |angle / half swath| ** power
    outer_dropout_prob: float = 0.0  # extra dropout probability reached at the swath edge
    outer_dropout_start_deg: float = 45.0  # beam angle where the extra dropouts start (deg)
    line_offset_sigma_m: float = 0.0  # std of a vertical offset per survey line (m)
    object_roughness_sigma_m: float = 0.0  # std of the normal displacement of object surfaces (m)

    def __post_init__(self):
        def bad(key, why):
            raise ValueError(f"sensor.realism.{key} {why}, got {getattr(self, key)!r}")

        for key in ("footprint_n_across", "footprint_n_along"):
            v = getattr(self, key)
            if isinstance(v, bool) or int(v) != v or v < 1:
                bad(key, "must be an integer >= 1")
        for key in ("beamwidth_across_deg", "beamwidth_along_deg", "roll_period_s", "pitch_period_s",
                    "yaw_period_s", "heave_period_s"):
            if not getattr(self, key) > 0:
                bad(key, "must be > 0")
        for key in ("range_quantum_m", "roll_bias_sigma_deg", "pitch_bias_sigma_deg", "roll_amplitude_deg",
                    "pitch_amplitude_deg", "yaw_amplitude_deg", "heave_amplitude_m", "svp_bias_sigma",
                    "outlier_magnitude_m", "outlier_outer_power", "line_offset_sigma_m",
                    "object_roughness_sigma_m"):
            if not getattr(self, key) >= 0:
                bad(key, "must be >= 0")
        for key in ("outlier_prob", "outer_dropout_prob"):
            if not 0.0 <= getattr(self, key) <= 1.0:
                bad(key, "must be in [0, 1]")
        for key in ("detection_switch_deg", "outer_dropout_start_deg"):
            if not 0.0 <= getattr(self, key) < 90.0:
                bad(key, "must be in [0, 90)")
        if self.detection not in DETECTION_MODES:
            bad("detection", f"must be one of {', '.join(DETECTION_MODES)}")
        for key in ("roll_bias_deg", "pitch_bias_deg", "surface_sound_speed_error_mps", "svp_bias_coeff"):
            if not np.isfinite(getattr(self, key)):
                bad(key, "must be finite")
        if abs(self.roll_bias_deg) >= 45 or abs(self.pitch_bias_deg) >= 45:
            raise ValueError("sensor.realism.roll_bias_deg and pitch_bias_deg must be within +-45 deg")

    @classmethod
    def from_config(cls, d: dict | None) -> "RealismConfig":
        """Build from the `sensor.realism` mapping; None or {} give the all-off profile.

        Unknown keys raise ValueError naming them (the config schema rejects them too).
        """
        d = dict(d or {})
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"sensor.realism: unknown key(s) {', '.join(unknown)} "
                             f"(allowed: {', '.join(sorted(names))})")
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def n_subrays(self) -> int:
        return int(self.footprint_n_across) * int(self.footprint_n_along)

    @property
    def steers_rays(self) -> bool:
        """True if the rays leave with another attitude, position or angle than the nominal ones."""
        return any(v != 0 for v in (
            self.roll_bias_deg, self.roll_bias_sigma_deg, self.pitch_bias_deg, self.pitch_bias_sigma_deg,
            self.roll_amplitude_deg, self.pitch_amplitude_deg, self.yaw_amplitude_deg, self.heave_amplitude_m,
            self.surface_sound_speed_error_mps))

    @property
    def active(self) -> bool:
        """True if any effect is on (False: the scan runs its plain path)."""
        return self.n_subrays > 1 or self.steers_rays or any(v != 0 for v in (
            self.range_quantum_m, self.svp_bias_coeff, self.svp_bias_sigma, self.outlier_prob,
            self.outer_dropout_prob, self.line_offset_sigma_m, self.object_roughness_sigma_m))


def child_rng(rng: np.random.Generator) -> np.random.Generator:
    """A generator for the realism effects that leaves `rng`'s stream untouched (a spawned child).

    Generators without a seed sequence fall back to one seeded from `rng` (which then advances).
    """
    try:
        return rng.spawn(1)[0]
    except (TypeError, ValueError, AttributeError):
        return np.random.default_rng(int(rng.integers(0, 2**63)))


@dataclass
class LineParams:
    """Random per-line quantities, one entry per line of `lines`: roll and pitch bias (rad),
    sinusoid phases (rad) of roll, pitch, yaw and heave, SVP coefficient k, vertical offset (m)."""

    lines: np.ndarray
    roll_bias: np.ndarray
    pitch_bias: np.ndarray
    phase: np.ndarray  # (L, 4): roll, pitch, yaw, heave
    svp_k: np.ndarray
    offset_m: np.ndarray

    def index(self, line: np.ndarray) -> np.ndarray:
        """Position in `lines` of each entry of `line`."""
        return np.searchsorted(self.lines, line)


def draw_line_params(cfg: RealismConfig, lines, rng: np.random.Generator) -> LineParams:
    """Per-line biases, phases and offsets for the sorted unique `lines`. Always draws the same
    numbers in the same order, so turning one effect on does not change another's draws."""
    lines = np.unique(np.asarray(lines))
    n = len(lines)
    z = rng.standard_normal((n, 4))
    phase = rng.uniform(0.0, 2.0 * np.pi, (n, 4))
    return LineParams(
        lines=lines,
        roll_bias=np.deg2rad(cfg.roll_bias_deg + cfg.roll_bias_sigma_deg * z[:, 0]),
        pitch_bias=np.deg2rad(cfg.pitch_bias_deg + cfg.pitch_bias_sigma_deg * z[:, 1]),
        phase=phase,
        svp_k=cfg.svp_bias_coeff + cfg.svp_bias_sigma * z[:, 2],
        offset_m=cfg.line_offset_sigma_m * z[:, 3],
    )


def ping_times_s(position: np.ndarray, line: np.ndarray, speed_mps: float) -> np.ndarray:
    """Time (s, (P,)) of each ping since the first ping of its line: along-track distance / speed."""
    position = np.asarray(position, dtype=np.float64)
    step = np.r_[0.0, np.linalg.norm(np.diff(position[:, :2], axis=0), axis=1)]
    start = np.r_[True, line[1:] != line[:-1]]
    step[start] = 0.0
    cum = np.cumsum(step)
    # Restart the clock at each line start.
    first = np.maximum.accumulate(np.where(start, np.arange(len(step)), 0))
    return (cum - cum[first]) / float(speed_mps)


def motion(cfg: RealismConfig, t_s: np.ndarray, phase: np.ndarray):
    """Sinusoidal roll, pitch, yaw (rad) and heave (m, + up), each (P,), at ping times t_s (s) with
    per-ping phases (P, 4) (roll, pitch, yaw, heave)."""
    w = 2.0 * np.pi * t_s

    def sine(amp, period, k):
        return amp * np.sin(w / period + phase[:, k])

    return (sine(np.deg2rad(cfg.roll_amplitude_deg), cfg.roll_period_s, 0),
            sine(np.deg2rad(cfg.pitch_amplitude_deg), cfg.pitch_period_s, 1),
            sine(np.deg2rad(cfg.yaw_amplitude_deg), cfg.yaw_period_s, 2),
            sine(cfg.heave_amplitude_m, cfg.heave_period_s, 3))


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


def steered_angles(angles_rad: np.ndarray, cfg: RealismConfig, sound_speed_mps: float) -> np.ndarray:
    """True across-track angles (rad) of beams steered to `angles_rad` with the assumed sound speed
    sound_speed_mps + surface_sound_speed_error_mps when the water's is sound_speed_mps (Snell)."""
    assumed = sound_speed_mps + cfg.surface_sound_speed_error_mps
    if assumed <= 0:
        raise ValueError("sensor.realism.surface_sound_speed_error_mps makes the assumed sound speed <= 0")
    return np.arcsin(np.clip(np.sin(angles_rad) * (sound_speed_mps / assumed), -1.0, 1.0))


def subray_bundle(cfg: RealismConfig):
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


def roughness_range_offsets(t, mesh_id, cos_incidence, sigma_m: float, rng: np.random.Generator) -> np.ndarray:
    """Range changes (m, shape of t) of hits on a surface displaced along its normal by N(0, sigma_m^2):
    d / |cos(incidence)| for hits on meshes with id >= 0, 0 elsewhere."""
    d = sigma_m * rng.standard_normal(np.shape(t))
    on_object = np.isfinite(t) & (np.asarray(mesh_id) >= 0)
    return np.where(on_object, d / np.maximum(np.abs(cos_incidence), _MIN_COS_INCIDENCE), 0.0)


def angle_weight(angles_rad: np.ndarray, half_swath_rad: float, power: float) -> np.ndarray:
    """|angle / half swath| ** power per beam (1 everywhere for power 0)."""
    return np.abs(np.asarray(angles_rad) / half_swath_rad) ** power


def outlier_probability(cfg: RealismConfig, angles_rad: np.ndarray, all_angles_rad: np.ndarray,
                        half_swath_rad: float) -> np.ndarray:
    """Spike probability per beam of angles_rad, normalised so its mean over the full fan
    all_angles_rad is outlier_prob (capped at 1)."""
    if cfg.outlier_prob <= 0:
        return np.zeros(len(angles_rad))
    norm = angle_weight(all_angles_rad, half_swath_rad, cfg.outlier_outer_power).mean()
    if norm <= 0:  # a single nadir beam with power > 0
        return np.full(len(angles_rad), cfg.outlier_prob)
    w = angle_weight(angles_rad, half_swath_rad, cfg.outlier_outer_power) / norm
    return np.minimum(cfg.outlier_prob * w, 1.0)


def outlier_offsets(shape, p_beam: np.ndarray, magnitude_m: float, rng: np.random.Generator) -> np.ndarray:
    """Range offsets (m, shape (P,B)): +-U(0.1, 1) x magnitude_m with probability p_beam (B,), else 0."""
    u = rng.random(shape)
    size = rng.uniform(0.1, 1.0, shape) * magnitude_m
    sign = np.where(rng.random(shape) < 0.5, -1.0, 1.0)
    return np.where(u < p_beam[None, :], sign * size, 0.0)


def outer_dropout_probability(cfg: RealismConfig, angles_rad: np.ndarray, half_swath_rad: float) -> np.ndarray:
    """Extra dropout probability per beam (B,): 0 inside outer_dropout_start_deg, rising
    quadratically to outer_dropout_prob at the swath edge."""
    start = np.deg2rad(cfg.outer_dropout_start_deg)
    if cfg.outer_dropout_prob <= 0 or start >= half_swath_rad:
        return np.zeros(len(angles_rad))
    u = np.clip((np.abs(angles_rad) - start) / (half_swath_rad - start), 0.0, 1.0)
    return cfg.outer_dropout_prob * u * u


def quantise(r: np.ndarray, step_m: float) -> np.ndarray:
    """Ranges rounded to multiples of step_m (m); unchanged for step_m = 0."""
    if step_m <= 0:
        return r
    return np.round(np.asarray(r, dtype=np.float64) / step_m) * step_m


def svp_bias_dz(k, depth_m, cos_vertical) -> np.ndarray:
    """Elevation change (m, + up) of the water-column sound-speed bias: k D (1/cos a - 1) for depth
    D (m) below the transducer and vertical beam angle a."""
    return k * depth_m * (1.0 / np.maximum(cos_vertical, 1e-6) - 1.0)


def swath_margin_m(cfg: RealismConfig | None, altitude_m: float, half_swath_rad: float,
                   sound_speed_mps: float) -> float:
    """Extra distance (m) beyond the nominal swath that the rays of this profile can reach on a flat
    seabed altitude_m below the transducer (attitude, footprint, steering error; random per-line
    biases at 4 sigma); 0 for no profile. Geometry culled to the swath needs this margin."""
    if cfg is None or not cfg.active:
        return 0.0
    steer = abs(float(steered_angles(np.array([half_swath_rad]), cfg, sound_speed_mps)[0]) - half_swath_rad)
    across = np.deg2rad(abs(cfg.roll_bias_deg) + 4 * cfg.roll_bias_sigma_deg + cfg.roll_amplitude_deg
                        + 0.5 * cfg.beamwidth_across_deg) + steer
    along = np.deg2rad(abs(cfg.pitch_bias_deg) + 4 * cfg.pitch_bias_sigma_deg + cfg.pitch_amplitude_deg
                       + 0.5 * cfg.beamwidth_along_deg)
    depth = altitude_m + cfg.heave_amplitude_m
    edge = min(half_swath_rad + across, np.deg2rad(85.0))
    half_w = depth * np.tan(edge)
    return float(max(half_w - altitude_m * np.tan(half_swath_rad),
                     depth * np.tan(along) + half_w * np.sin(np.deg2rad(cfg.yaw_amplitude_deg))))


def burial_depths(groups, burial_m, rng: np.random.Generator) -> np.ndarray:
    """Depth (m, >= 0) by which each object sinks into the sediment, drawn uniformly from
    burial_m = (min, max). Objects of one arrangement group (group >= 0: a pile, a stack, a cone
    cluster) sink together by one depth; scattered objects (group -1) draw their own."""
    groups = np.asarray(groups, dtype=np.int64)
    lo, hi = float(burial_m[0]), float(burial_m[1])
    if lo < 0 or hi < lo:
        raise ValueError(f"scenes.realism.burial_m must be [min, max] with 0 <= min <= max, got {list(burial_m)}")
    own = rng.uniform(lo, hi, len(groups))
    uniq = np.unique(groups[groups >= 0])
    per_group = rng.uniform(lo, hi, len(uniq))
    shared = per_group[np.searchsorted(uniq, np.maximum(groups, 0))] if len(uniq) else own
    return np.where(groups >= 0, shared, own)
