"""The methods registry: every detection method the workflow runs, evaluates, times and reports
belongs to a registered :class:`MethodFamily` (in the style of OpenPCDet's model tables).

Built-in families: `model_based` (model_based_{variant}), `sasa` (sasa_{fraction}), `sasa_dr`
(sasa_dr_{fraction}). A plugin (config key `plugins`) registers more with :func:`register`; their
settings live under the config's `methods.{family}`.
"""

from __future__ import annotations

from .base import RESOURCE_KINDS, RUNNERS, Detector, Method, MethodFamily, Resources
from .model_based import ModelBased
from .sasa import Sasa, SasaDomainRandomised, SasaSeeds

__all__ = ["RESOURCE_KINDS", "RUNNERS", "Detector", "Method", "MethodFamily", "Resources", "check", "configured",
           "families", "family", "get", "main_methods", "register", "shared_runs", "variants"]

_FAMILIES: dict[str, MethodFamily] = {}


def register(family: MethodFamily) -> MethodFamily:
    """Add a method family (an instance); re-registering a name replaces it. Returns the family."""
    if not family.name or not family.name.replace("_", "").isalnum():
        raise ValueError(f"method family name {family.name!r}: use letters, digits and '_'")
    _FAMILIES[family.name] = family
    return family


def families() -> list[MethodFamily]:
    """Registered families, in registration order."""
    return list(_FAMILIES.values())


def family(name: str) -> MethodFamily:
    """The family called `name`; KeyError naming the registered ones otherwise."""
    try:
        return _FAMILIES[name]
    except KeyError:
        raise KeyError(f"unknown method family {name!r}; registered: {', '.join(_FAMILIES)}") from None


def configured(config: dict) -> list[Method]:
    """Every method the validated config asks for: family by family in registration order, each in
    its config order."""
    return [m for f in _FAMILIES.values() for m in f.methods(config)]


def main_methods(config: dict) -> list[Method]:
    """The configured methods compared in the main tables (group 'main')."""
    return [m for m in configured(config) if m.group == "main"]


def variants(config: dict, group: str | None = None) -> list[Method]:
    """The configured variants of other methods (e.g. SASA with domain randomisation), all or those of
    one report group."""
    return [m for m in configured(config) if m.variant_of is not None and (group is None or m.group == group)]


def get(name: str, config: dict) -> Method:
    """The method called `name`: a configured one, else the first family that recognises the name
    (e.g. `sasa_30` for a model trained elsewhere). ValueError naming the configured methods otherwise."""
    for m in configured(config):
        if m.name == name:
            return m
    for f in _FAMILIES.values():
        m = f.parse(name, config)
        if m is not None:
            return m
    known = ", ".join(m.name for m in configured(config))
    raise ValueError(f"unknown method {name!r}; configured methods: {known} (families: {', '.join(_FAMILIES)})")


def shared_runs(methods: list[Method], runner: str = "per_scene") -> list[list[Method]]:
    """The methods of `methods` with the given runner in groups that run together on a dataset (one
    job), each group in the order given; groups of one method included, ordered by their first member.
    Per-scene methods group within a family (`MethodFamily.share_key`, one detector:
    `MethodFamily.load_shared`); per-dataset ones by `MethodFamily.dataset_share_key` across
    families (run by `MethodFamily.detect_datasets` of the first member's family)."""
    if runner not in RUNNERS:
        raise ValueError(f"runner {runner!r} is not one of {RUNNERS}")
    groups: dict = {}
    for m in methods:
        if m.runner != runner:
            continue
        fam = _FAMILIES.get(m.family)
        if runner == "per_scene":
            key = fam.share_key(m) if fam is not None else None
            key = (m.family, key) if key is not None else None
        else:
            key = fam.dataset_share_key(m) if fam is not None else None
        groups.setdefault(key if key is not None else ("", m.name), []).append(m)
    return list(groups.values())


def check(config: dict) -> list[str]:
    """Problems of the methods' config sections (each naming its key): every family's own checks,
    unknown families under `methods`, duplicate method names."""
    out = []
    for name in config.get("methods", {}) or {}:
        if name not in _FAMILIES:
            out.append(f"methods.{name}: no registered method family of that name (registered: "
                       f"{', '.join(_FAMILIES)}); list the module that registers it under `plugins`")
    for f in _FAMILIES.values():
        out += f.check(config)
    seen = set()
    for m in configured(config) if not out else []:
        if m.name in seen:
            out.append(f"method {m.name!r} is configured twice (two families make the same name)")
        seen.add(m.name)
    return out


register(ModelBased())
register(Sasa())
register(SasaDomainRandomised())
register(SasaSeeds())
