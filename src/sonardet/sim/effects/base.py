"""The parts an effect is made of: its config keys (:class:`Key`), the :class:`Effect` record, and the
state of a realistic scan that effects read and change (:class:`ScanSetup` once per scan,
:class:`ScanChunk` per chunk of pings).

Frames and units follow :mod:`sonardet.sim.mbes`: scene frame x east, y north, z up, metres, radians
inside the code, degrees only in config keys ending `_deg`. The sonar body frame is x forward,
y starboard, z down; roll is positive starboard-down, pitch positive bow-up, yaw positive
counter-clockwise seen from above.

Stages, in the order a survey meets them (:data:`STAGES`):

* ``scene``: the world before the survey (object burial); applied by the scene builders
  (:mod:`sonardet.sim.scene`, :mod:`sonardet.sim.hybrid`), keys under `scenes.realism`.
* ``ray``: how the rays leave the transducer (attitude, beam steering).
* ``range``: the range each (sub-)ray measures, right after the cast (object roughness).
* ``sounding``: how a beam's sounding is formed and reported: the sub-ray bundle and detection,
  dropouts, spikes, range quantisation (after the sensor's own dropouts and range noise).
* ``point``: the georeferenced soundings (sound-speed profile bias, line offsets).

Every stage but ``scene`` takes its keys from `sensor.realism` (:class:`RealismConfig
<sonardet.sim.effects.registry.RealismConfig>`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

#: Stages an effect can act at, in the order a survey meets them.
STAGES = ("scene", "ray", "range", "sounding", "point")
#: Config section of an effect's keys, by stage.
SCENE_SECTION = "scenes.realism"
SENSOR_SECTION = "sensor.realism"


# --- key checks: each returns None for a valid value, else why it is not ------------------------------

def integer_at_least(low: int) -> Callable[[Any], str | None]:
    """Check: an integer (not a bool) >= low."""
    def check(v):
        if isinstance(v, bool) or int(v) != v or v < low:
            return f"must be an integer >= {low}"
        return None
    return check


def positive(v) -> str | None:
    """Check: > 0."""
    return None if v > 0 else "must be > 0"


def non_negative(v) -> str | None:
    """Check: >= 0."""
    return None if v >= 0 else "must be >= 0"


def probability(v) -> str | None:
    """Check: in [0, 1]."""
    return None if 0.0 <= v <= 1.0 else "must be in [0, 1]"


def angle_below_90(v) -> str | None:
    """Check: an angle (deg) in [0, 90)."""
    return None if 0.0 <= v < 90.0 else "must be in [0, 90)"


def finite(v) -> str | None:
    """Check: a finite number."""
    return None if np.isfinite(v) else "must be finite"


def one_of(*choices: str) -> Callable[[Any], str | None]:
    """Check: one of `choices`."""
    def check(v):
        return None if v in choices else f"must be one of {', '.join(choices)}"
    return check


def min_max_range(v) -> str | None:
    """Check: [min, max] of two numbers with 0 <= min <= max."""
    try:
        lo, hi = (float(x) for x in v)
    except (TypeError, ValueError):
        return "must be [min, max] with 0 <= min <= max"
    return None if 0 <= lo <= hi else "must be [min, max] with 0 <= min <= max"


@dataclass(frozen=True)
class Key:
    """One config key of an effect.

    name: the key (units in the name: _m, _deg, _s, _mps); default: the value that leaves the
    effect off (or a neutral setting); unit: "m", "deg", "s", "m/s" or "" (counts, ratios, flags,
    modes); doc: what it sets (the config schema's description); schema: its JSON-schema type and
    bounds (without default and description); checks: functions value -> None or why it is invalid.
    """

    name: str
    default: Any
    unit: str
    doc: str
    schema: dict = field(default_factory=dict)
    checks: tuple = ()
    type: type = float

    def problem(self, value) -> str | None:
        """Why `value` is invalid for this key, or None."""
        for check in self.checks:
            why = check(value)
            if why:
                return why
        return None

    def json_schema(self) -> dict:
        """The key's JSON-schema property: its schema plus default and description."""
        default = list(self.default) if isinstance(self.default, tuple) else self.default
        return {**self.schema, "default": default, "description": self.doc}


@dataclass
class Reach:
    """How far an effect lets the rays reach beyond the nominal swath (for culling geometry to it):
    extra across-track angle (deg), along-track angle (deg), extra steering (rad), transducer
    lift (m, + up) and yaw wobble (deg). Effects' reaches add up."""

    across_deg: float = 0.0
    along_deg: float = 0.0
    steer_rad: float = 0.0
    up_m: float = 0.0
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class Effect:
    """One sensor realism effect.

    name: unique name (letters, digits, '_'); stage: one of :data:`STAGES`; keys: its config keys
    (`sensor.realism` for sensor stages, `scenes.realism` for ``scene``); doc: the model in a few
    lines; group: its realism-ablation group (default: name; effects of one group are switched on
    together); order: its place within its stage (effects of a stage apply in increasing order);
    switches: keys whose non-zero value turns the effect on; is_on(cfg): overrides `switches`;
    steers: when on, the rays leave with another attitude, position or angle than the nominal ones;
    check(cfg): a message for an invalid combination of keys, or None; reach(cfg, half_swath_rad,
    sound_speed_mps): its :class:`Reach`.

    How it is applied (sensor stages; the scan in :mod:`sonardet.sim.mbes` calls them):
    setup(cfg, setup: ScanSetup): once per realistic scan, whether the effect is on or not (with its
    keys at their defaults it must leave the scan a plain one); apply(cfg, setup, chunk: ScanChunk,
    rng): per chunk of pings at the effect's stage, only when the effect is on; draws from `rng`,
    the realism generator. Scene-stage effects give their functions to the scene builders instead.
    """

    name: str
    stage: str
    keys: tuple[Key, ...]
    doc: str
    group: str = ""
    order: int = 0
    switches: tuple[str, ...] = ()
    is_on: Callable[[Any], bool] | None = None
    steers: bool = False
    check: Callable[[Any], str | None] | None = None
    reach: Callable[..., Reach] | None = None
    setup: Callable[[Any, ScanSetup], None] | None = None
    apply: Callable[[Any, ScanSetup, ScanChunk, np.random.Generator], None] | None = None

    def __post_init__(self):
        if not self.name or not self.name.replace("_", "").isalnum():
            raise ValueError(f"effect name {self.name!r}: use letters, digits and '_' only")
        if self.stage not in STAGES:
            raise ValueError(f"effect {self.name}: stage {self.stage!r} is not one of {', '.join(STAGES)}")
        names = [k.name for k in self.keys]
        if len(set(names)) != len(names):
            raise ValueError(f"effect {self.name}: duplicate keys in {names}")
        unknown = sorted(set(self.switches) - set(names))
        if unknown:
            raise ValueError(f"effect {self.name}: switches {unknown} are not among its keys {names}")
        if not self.group:
            object.__setattr__(self, "group", self.name)

    @property
    def section(self) -> str:
        """Config section of the keys: `scenes.realism` (scene stage) or `sensor.realism`."""
        return SCENE_SECTION if self.stage == "scene" else SENSOR_SECTION

    def on(self, cfg) -> bool:
        """True if the effect changes anything under `cfg` (a RealismConfig or a mapping of its keys)."""
        get = cfg.get if isinstance(cfg, dict) else (lambda k: getattr(cfg, k))
        if self.is_on is not None:
            return bool(self.is_on(cfg))
        return any(get(k) != 0 for k in self.switches)

    def validate(self, cfg) -> None:
        """Raise ValueError with the first of :meth:`problems` (a message naming `<section>.<key>`)."""
        problems = self.problems(cfg)
        if problems:
            raise ValueError(problems[0])

    def problems(self, cfg) -> list[str]:
        """Messages naming `<section>.<key>` for every invalid key of `cfg`, then the combination check."""
        get = cfg.get if isinstance(cfg, dict) else (lambda k: getattr(cfg, k))
        out = []
        for key in self.keys:
            why = key.problem(get(key.name))
            if why:
                out.append(f"{self.section}.{key.name} {why}, got {get(key.name)!r}")
        if not out and self.check is not None:
            msg = self.check(cfg)
            if msg:
                out.append(msg)
        return out


# --- the state of a realistic scan --------------------------------------------------------------------

@dataclass
class LineDraws:
    """Random numbers per survey line, drawn once per scan in a fixed order whatever is on, so turning
    one effect on changes no other effect's draws: `normal` (L, 4) standard normals (columns: roll
    bias, pitch bias, sound-speed profile coefficient, vertical offset), `phase` (L, 4) uniform
    phases in [0, 2 pi) (rad; columns: roll, pitch, yaw, heave), one row per entry of the sorted
    unique `lines`."""

    lines: np.ndarray
    normal: np.ndarray
    phase: np.ndarray

    def index(self, line: np.ndarray) -> np.ndarray:
        """Row in `lines` of each entry of `line`."""
        return np.searchsorted(self.lines, line)


#: Columns of :class:`LineDraws`.normal and .phase.
ROLL, PITCH, SVP, OFFSET = 0, 1, 2, 3
YAW, HEAVE = 2, 3


def draw_lines(lines, rng: np.random.Generator) -> LineDraws:
    """The per-line draws (:class:`LineDraws`) for the lines of `lines` (any order, repeats allowed)."""
    lines = np.unique(np.asarray(lines))
    n = len(lines)
    normal = rng.standard_normal((n, 4))
    phase = rng.uniform(0.0, 2.0 * np.pi, (n, 4))
    return LineDraws(lines, normal, phase)


def child_rng(rng: np.random.Generator) -> np.random.Generator:
    """A generator for the realism effects that leaves `rng`'s stream untouched (a spawned child).

    Generators without a seed sequence fall back to one seeded from `rng` (which then advances).
    """
    try:
        return rng.spawn(1)[0]
    except (TypeError, ValueError, AttributeError):
        return np.random.default_rng(int(rng.integers(0, 2**63)))


@dataclass
class ScanSetup:
    """What a realistic scan knows before its first cast; ray- and sounding-stage effects set it up.

    Given: angles_rad (B,) nominal across-track angles of the cast beams, all_angles_rad (n_beams,)
    the whole fan, half_swath_rad, sound_speed_mps, lines (:class:`LineDraws`), line_index (P,) row
    of `lines` per ping, t_s (P,) time of each ping since its line's first (s).

    Set by effects (defaults: the plain sensor): roll_rad, pitch_rad, yaw_rad (P,) the true attitude
    offsets and heave_m (P,) the true transducer lift (m, + up) of each ping; georef_motion: None
    (the soundings are georeferenced with the nominal attitude) or (roll, pitch, yaw, heave) per ping
    known to the georeferencing; across_rad (B,) true across-track beam angles; sub_across_rad,
    sub_along_rad, sub_weight (S,) the sub-ray offsets (rad) and weights of a beam; phase_beam (B,)
    weighted-median detection per beam (else weighted mean); first: first-arrival detection;
    extra_dropout_prob (B,) float32 or None: dropout probability added to the sensor's; values: any
    per-effect results of setup, by effect name.
    """

    angles_rad: np.ndarray
    all_angles_rad: np.ndarray
    half_swath_rad: float
    sound_speed_mps: float
    lines: LineDraws
    line_index: np.ndarray
    t_s: np.ndarray
    roll_rad: np.ndarray = None
    pitch_rad: np.ndarray = None
    yaw_rad: np.ndarray = None
    heave_m: np.ndarray = None
    georef_motion: tuple | None = None
    across_rad: np.ndarray = None
    sub_across_rad: np.ndarray = field(default_factory=lambda: np.zeros(1))
    sub_along_rad: np.ndarray = field(default_factory=lambda: np.zeros(1))
    sub_weight: np.ndarray = field(default_factory=lambda: np.ones(1))
    phase_beam: np.ndarray = None
    first: bool = False
    extra_dropout_prob: np.ndarray | None = None
    values: dict = field(default_factory=dict)

    def __post_init__(self):
        n_ping, n_beam = len(self.line_index), len(self.angles_rad)
        for name in ("roll_rad", "pitch_rad", "yaw_rad", "heave_m"):
            if getattr(self, name) is None:
                setattr(self, name, np.zeros(n_ping))
        if self.across_rad is None:
            self.across_rad = np.asarray(self.angles_rad, dtype=np.float64)
        if self.phase_beam is None:
            self.phase_beam = np.zeros(n_beam, dtype=bool)

    def add_dropout_probability(self, p_beam: np.ndarray) -> None:
        """Add a dropout probability per beam (B,) to the sensor's (float32, as the sensor's)."""
        p = np.asarray(p_beam).astype(np.float32)
        self.extra_dropout_prob = p if self.extra_dropout_prob is None else self.extra_dropout_prob + p


@dataclass
class ScanChunk:
    """One chunk of pings of a realistic scan, as the stages leave it.

    pings: slice of the scan's pings; position (n, 3) m and heading_rad (n,) of the pings; line_row
    (n,) row of each ping in the setup's :class:`LineDraws`. After the cast (range stage): dirs
    (n, B, S, 3) true sub-ray directions, t (n, B, S) sub-ray ranges (m, inf = miss), mesh (n, B, S)
    mesh ids hit, cos_incidence (n, B, S). After detection and the sensor's dropouts and noise
    (sounding stage): r (n, B) beam ranges (m), keep (n, B) soundings kept. After georeferencing
    (point stage): geo_dir (n, B, 3) the directions the georeferencing assumed, dz (n, B) or None:
    the vertical displacement (m, + up) effects add (:meth:`add_dz`).
    """

    pings: slice
    position: np.ndarray
    heading_rad: np.ndarray
    line_row: np.ndarray
    dirs: np.ndarray = None
    t: np.ndarray = None
    mesh: np.ndarray = None
    cos_incidence: np.ndarray = None
    r: np.ndarray = None
    keep: np.ndarray = None
    geo_dir: np.ndarray = None
    dz: np.ndarray | None = None

    def add_dz(self, dz: np.ndarray) -> None:
        """Add a vertical displacement (m, + up) of the soundings (n, B) to those of earlier effects."""
        self.dz = dz if self.dz is None else self.dz + dz
