"""The registry of sensor effects, and what is derived from it.

The registry is an ordered list of :class:`~sonardet.sim.effects.base.Effect`. Its order is that of
the config keys (the fields of :class:`RealismConfig`, the schema) and of the realism ablation's
groups; the order in which effects act is their stage, then their `order`
(:func:`pipeline`). Derived from it:

* :class:`RealismConfig`: one field per key of every sensor-stage effect, with the key's default;
  validation by the effects' checks (messages name `sensor.realism.<key>`); `active` and
  `steers_rays` from the effects' switches;
* :func:`effect_groups` and the live mapping :data:`REALISM_EFFECT_GROUPS`: the realism ablation's
  standard groups, group -> keys (a scene-stage key such as `burial_m` stands for its
  `scenes.realism` value);
* :func:`realism_schema`: the JSON-schema properties of `sensor.realism` and `scenes.realism`.

:func:`register` adds an effect (a plugin calls it at import); RealismConfig is regenerated in
place, so references to the class stay valid.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from .base import STAGES, Effect, Key

_EFFECTS: list[Effect] = []
#: Names a key may not take: RealismConfig's own attributes.
_RESERVED = frozenset({"from_config", "to_dict", "active", "steers_rays"})


def effects(stage: str | None = None) -> tuple[Effect, ...]:
    """The registered effects in registry order, optionally only those of one stage."""
    if stage is not None and stage not in STAGES:
        raise ValueError(f"unknown stage {stage!r} (stages: {', '.join(STAGES)})")
    return tuple(e for e in _EFFECTS if stage is None or e.stage == stage)


def effect(name: str) -> Effect:
    """The registered effect called `name` (KeyError naming the registered ones otherwise)."""
    for e in _EFFECTS:
        if e.name == name:
            return e
    raise KeyError(f"no sensor effect {name!r} (registered: {', '.join(e.name for e in _EFFECTS)})")


def sensor_effects() -> tuple[Effect, ...]:
    """The effects whose keys live in `sensor.realism` (every stage but ``scene``), registry order."""
    return tuple(e for e in _EFFECTS if e.stage != "scene")


def pipeline(stage: str) -> tuple[Effect, ...]:
    """The effects of `stage` in the order they act (their `order`, then registry order)."""
    return tuple(sorted(effects(stage), key=lambda e: e.order))


def sensor_keys() -> tuple[Key, ...]:
    """Keys of `sensor.realism` (RealismConfig's fields), registry order."""
    return tuple(k for e in sensor_effects() for k in e.keys)


def effect_groups() -> dict[str, list[str]]:
    """The realism ablation's standard effect groups: group -> the keys of its effects, registry order."""
    out: dict[str, list[str]] = {}
    for e in _EFFECTS:
        out.setdefault(e.group, []).extend(k.name for k in e.keys)
    return {g: keys for g, keys in out.items() if keys}


class EffectGroups(Mapping):
    """A read-only, always current view of :func:`effect_groups` (group -> list of keys)."""

    def __getitem__(self, group: str) -> list[str]:
        return list(effect_groups()[group])

    def __iter__(self):
        return iter(effect_groups())

    def __len__(self) -> int:
        return len(effect_groups())

    def __repr__(self) -> str:
        return repr(effect_groups())


#: The standard effect groups of the realism ablation: effect group -> keys of `realism_test.sensor`
#: (or `burial_m`) that together make one physical effect; follows the registry.
REALISM_EFFECT_GROUPS = EffectGroups()


def realism_schema(section: str = "sensor") -> dict:
    """JSON-schema properties (key -> schema with default and description) of `sensor.realism`
    (section "sensor") or `scenes.realism` (section "scenes"), derived from the registered effects."""
    if section not in ("sensor", "scenes"):
        raise ValueError(f"section must be 'sensor' or 'scenes', got {section!r}")
    chosen = sensor_effects() if section == "sensor" else effects("scene")
    return {k.name: k.json_schema() for e in chosen for k in e.keys}


def register(new: Effect, replace: bool = False) -> Effect:
    """Add an effect at the end of the registry (or, with replace=True, in place of the one of the
    same name). Its keys must be new; RealismConfig gains its sensor keys. Returns the effect."""
    if not isinstance(new, Effect):
        raise TypeError(f"register() takes an Effect, got {type(new).__name__}")
    names = [e.name for e in _EFFECTS]
    if new.name in names and not replace:
        raise ValueError(f"sensor effect {new.name!r} is already registered (pass replace=True to replace it)")
    owner = {k.name: e.name for e in _EFFECTS if e.name != new.name for k in e.keys}
    clash = [f"{k.name} (of {owner[k.name]})" for k in new.keys if k.name in owner]
    if clash:
        raise ValueError(f"effect {new.name}: key(s) already taken: {', '.join(clash)}")
    bad = [k.name for k in new.keys if k.name.startswith("_") or k.name in _RESERVED]
    if bad:
        raise ValueError(f"effect {new.name}: reserved key name(s) {bad}")
    if new.stage != "scene":
        for k in new.keys:
            try:
                hash(k.default)
            except TypeError:
                raise ValueError(f"effect {new.name}: default of {k.name} must be hashable "
                                 f"(a number, string, bool or tuple), got {k.default!r}") from None
    if new.name in names:
        _EFFECTS[names.index(new.name)] = new
    else:
        _EFFECTS.append(new)
    _rebuild_realism_config()
    return new


def unregister(name: str) -> Effect:
    """Remove the effect called `name` (tests, plugins that replace a built-in); returns it."""
    gone = effect(name)
    _EFFECTS.remove(gone)
    _rebuild_realism_config()
    return gone


class RealismConfig:
    """Sensor realism effects (the `sensor.realism` config section); every default turns its effect off.

    A frozen dataclass with one field per key of the registered sensor-stage effects, in registry
    order (:func:`sensor_keys`). Units are in the names: metres (_m), degrees (_deg), seconds (_s),
    m/s (_mps); counts and probabilities are unitless. The models: the effect modules of
    :mod:`sonardet.sim.effects`.
    """

    def __post_init__(self):
        for e in sensor_effects():
            e.validate(self)

    @classmethod
    def from_config(cls, d: dict | None) -> RealismConfig:
        """Build from the `sensor.realism` mapping; None or {} give the all-off profile.

        Unknown keys raise ValueError naming them (the config schema rejects them too).
        """
        d = dict(d or {})
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"sensor.realism: unknown key(s) {', '.join(unknown)} "
                             f"(allowed: {', '.join(sorted(names))})")
        return cls(**d)

    def to_dict(self) -> dict:
        """The settings as a plain mapping, in field order."""
        return dataclasses.asdict(self)

    @property
    def steers_rays(self) -> bool:
        """True if the rays leave with another attitude, position or angle than the nominal ones."""
        return any(e.steers and e.on(self) for e in sensor_effects())

    @property
    def active(self) -> bool:
        """True if any effect is on (False: the scan runs its plain path)."""
        return any(e.on(self) for e in sensor_effects())


#: What dataclasses generates on a class; removed before RealismConfig is regenerated.
_GENERATED = ("__init__", "__repr__", "__eq__", "__hash__", "__setattr__", "__delattr__", "__match_args__",
              "__dataclass_fields__", "__dataclass_params__")


def _rebuild_realism_config() -> None:
    """Regenerate RealismConfig's dataclass machinery for the registered keys, on the same class."""
    cls = RealismConfig
    old = list(getattr(cls, "__dataclass_fields__", {}))
    for name in _GENERATED + tuple(old):
        if name in cls.__dict__:
            delattr(cls, name)
    keys = sensor_keys()
    cls.__annotations__ = {k.name: k.type for k in keys}
    for k in keys:
        setattr(cls, k.name, k.default)
    dataclasses.dataclass(frozen=True)(cls)


_rebuild_realism_config()
