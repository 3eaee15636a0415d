"""Workflow configuration: validation against the JSON schema, defaults, derived seeds and hashes.

The schema (`config/schema.yaml`, shipped in the package as `sonardet/data/schema.yaml`) documents
every key with units and default. Validation rejects unknown keys and wrong types or ranges with a
message that names the key path, so a bad config stops the run before any job starts.
"""

from __future__ import annotations

import copy
from importlib import resources
from pathlib import Path

import jsonschema
import yaml

from .sim.effects import REALISM_EFFECT_GROUPS


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range; the message names the key."""


def load_schema() -> dict:
    """The config JSON schema shipped with the package."""
    with resources.files("sonardet").joinpath("data/schema.yaml").open("r") as fh:
        return yaml.safe_load(fh)


def _resolve(schema: dict, root: dict) -> dict:
    while "$ref" in schema:
        ref = schema["$ref"]
        node = root
        for part in ref.lstrip("#/").split("/"):
            node = node[part]
        schema = {**node, **{k: v for k, v in schema.items() if k != "$ref"}}
    return schema


def _fill_defaults(instance, schema: dict, root: dict):
    """Insert schema defaults for missing keys, recursively; a given dict is completed from the
    property's default dict, so `tetrapod_s: {height_m: 1.5}` keeps the default mass."""
    schema = _resolve(schema, root)
    if not isinstance(instance, dict) or schema.get("type") != "object":
        return instance
    for key, sub in schema.get("properties", {}).items():
        sub_r = _resolve(sub, root)
        if key not in instance:
            if "default" in sub_r:
                instance[key] = copy.deepcopy(sub_r["default"])
            else:
                continue
        elif isinstance(instance[key], dict) and isinstance(sub_r.get("default"), dict):
            for dk, dv in sub_r["default"].items():
                instance[key].setdefault(dk, copy.deepcopy(dv))
        _fill_defaults(instance[key], sub_r, root)
    return instance


def _key_path(path) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out or "<top level>"


def _describe(err: jsonschema.ValidationError) -> str:
    where = _key_path(err.absolute_path)
    if err.validator == "additionalProperties":
        allowed = sorted(err.schema.get("properties", {}))
        extra = sorted(set(err.instance) - set(allowed)) if isinstance(err.instance, dict) else []
        keys = ", ".join(f"{where}.{k}" if where != "<top level>" else k for k in extra)
        return f"{keys}: unknown key (allowed here: {', '.join(allowed)})"
    if err.validator == "enum":
        return f"{where}: {err.instance!r} is not one of {err.validator_value}"
    return f"{where}: {err.message}"


def validate_config(config: dict, source: str = "config") -> dict:
    """Validate `config` against the schema and return a copy with every default filled in.

    Raises ConfigError listing every offending key (dotted path) with the reason and the source.
    """
    schema = load_schema()
    cfg = _fill_defaults(copy.deepcopy(dict(config)), schema, schema)
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(cfg), key=lambda e: list(map(str, e.absolute_path)))
    problems = [_describe(e) for e in errors] or _cross_checks(cfg)
    if problems:
        lines = "\n".join(f"  - {p}" for p in problems)
        raise ConfigError(f"invalid configuration ({source}):\n{lines}\nFix these keys; see config/schema.yaml.")
    return cfg


#: Horizontal footprint radius (m) of each class at the default dimensions, for the packing check.
_FOOTPRINT_R = {"reef_ring": 1.34, "reef_cone": 1.0, "tetrapod_b": 1.3, "tetrapod_s": 0.9}


def _cross_checks(cfg: dict) -> list[str]:
    """Constraints between keys that a JSON schema cannot express."""
    out = []
    sc = cfg["scenes"]
    if sc["seabed"]["mean_depth_m"] >= sc["survey"]["transducer_z_m"]:
        out.append(f"scenes.seabed.mean_depth_m: {sc['seabed']['mean_depth_m']} m is not below the transducer "
                   f"(scenes.survey.transducer_z_m = {sc['survey']['transducer_z_m']} m)")
    for key in ("n_objects", "n_rocks", "scatter_fraction", "cone_gap_m", "big_spacing_m", "rock_size_m"):
        lo, hi = sc[key]
        if lo > hi:
            out.append(f"scenes.{key}: [min, max] with min {lo} > max {hi}")
    for key in ("slope_deg", "amplitude_m"):
        lo, hi = sc["seabed"][key]
        if lo > hi:
            out.append(f"scenes.seabed.{key}: [min, max] with min {lo} > max {hi}")
    # More objects than fit: footprints of the largest count may cover at most 60 % of the scene.
    mix = {c: sc["class_mix"].get(c, 0.0) for c in cfg["classes"]}
    total = sum(mix.values())
    if total <= 0:
        out.append("scenes.class_mix: no weight on any class of `classes`")
    else:
        scale = {c: cfg["objects"][c]["height_m"] / d for c, d in
                 (("reef_ring", 0.75), ("reef_cone", 1.37), ("tetrapod_b", 2.08), ("tetrapod_s", 1.42))}
        area = sum(w / total * 3.14159 * (_FOOTPRINT_R[c] * scale[c]) ** 2 for c, w in mix.items())
        ex, ey = sc["extent_m"]
        if sc["n_objects"][1] * area > 0.6 * ex * ey:
            out.append(f"scenes.n_objects: up to {sc['n_objects'][1]} objects need about "
                       f"{sc['n_objects'][1] * area:.0f} m^2 of seabed, more than 60 % of the "
                       f"{ex} x {ey} m scene (scenes.extent_m); lower n_objects or enlarge the scene")
    ev = cfg["evaluation"]
    if ev["headline_m"] not in ev["dist_thresholds_m"]:
        out.append(f"evaluation.headline_m: {ev['headline_m']} is not one of evaluation.dist_thresholds_m "
                   f"{ev['dist_thresholds_m']}")
    out += _detector_checks(cfg)
    rt = cfg["realism_test"]
    if rt["enabled"]:
        derived = realism_test_config(cfg)
        derived["realism_test"] = {"enabled": False}
        derived["realism_ablation"] = {"enabled": False}
        try:
            validate_config(derived, source="realism_test")
        except ConfigError as exc:
            for line in str(exc).splitlines():
                if line.startswith("  - "):
                    out.append(line[4:].replace("sensor.realism", "realism_test.sensor")
                               .replace("scenes.realism.burial_m", "realism_test.burial_m"))
    out += _realism_ablation_checks(cfg)
    dr = cfg["domain_randomisation"]
    if dr["enabled"]:
        bad = [f for f in dr["fractions"] if f not in cfg["split"]["fractions"]]
        if bad:
            out.append(f"domain_randomisation.fractions: {bad} not among split.fractions {cfg['split']['fractions']}")
    if cfg["split"]["n_test"] >= sc["n_scenes"]:
        out.append(f"split.n_test: {cfg['split']['n_test']} test scenes leave none of the "
                   f"{sc['n_scenes']} scenes (scenes.n_scenes) for training")
    return out


def _realism_ablation_checks(cfg: dict) -> list[str]:
    """The one-at-a-time realism ablation needs the realism test set, known effect keys that change
    something, and configured methods."""
    ra = cfg["realism_ablation"]
    if not ra["enabled"]:
        return []
    out = []
    rt = cfg["realism_test"]
    if not rt["enabled"]:
        return ["realism_ablation.enabled: needs realism_test.enabled (the effects take its values)"]
    effects = realism_effects(cfg)
    if not effects:
        out.append("realism_ablation.effects: no effect to ablate (realism_test sets none of the standard keys)")
    for name, keys in effects.items():
        if not name.replace("_", "").isalnum():
            out.append(f"realism_ablation.effects.{name}: use letters, digits and '_' only (it becomes a folder name)")
        for k in keys:
            if k == "burial_m":
                if max(rt["burial_m"]) <= 0:
                    out.append(f"realism_ablation.effects.{name}: burial_m is [0, 0] in realism_test.burial_m, "
                               "so the effect would change nothing")
            elif k not in rt["sensor"]:
                out.append(f"realism_ablation.effects.{name}: key {k!r} is not set in realism_test.sensor "
                           f"(set there: {sorted(rt['sensor'])})")
    methods = {f"model_based_{v}" for v in cfg["model_based"]["variants"]}
    if cfg["sasa"]["enabled"]:
        methods |= {f"sasa_{f}" for f in cfg["split"]["fractions"]}
        if cfg["domain_randomisation"]["enabled"]:
            methods |= {f"sasa_dr_{f}" for f in cfg["domain_randomisation"]["fractions"]}
    for m in ra["methods"]:
        if m not in methods:
            out.append(f"realism_ablation.methods: {m!r} is not a configured method ({sorted(methods)})")
    return out


def _detector_checks(cfg: dict) -> list[str]:
    """Detector hyper-parameter overrides: unknown keys and invalid values, named by their config path."""
    from sonardet.detect.model_based import params as mb
    from sonardet.detect.sasa import config as sasa

    out = []
    for variant in ("paper", "ours"):
        try:
            mb.resolve_params(cfg["model_based"][variant], variant)
        except (ValueError, TypeError) as exc:
            out.append(f"model_based.{variant}: {exc}")
    s = cfg["sasa"]
    for key in ("seed", "classes"):
        if key in s["params"]:
            out.append(f"sasa.params.{key}: set by the top-level key `{key}`; remove it here")
    try:
        sasa.resolve_params(s["params"], sasa.PAPER if s["preset"] == "paper" else sasa.DEFAULTS)
    except (ValueError, TypeError) as exc:
        out.append(f"sasa.params: {exc}")
    from sonardet.ablation import check_points

    ab = cfg["ablation"]
    out += check_points(ab["points"], cfg["split"]["fractions"])
    for i, pt in enumerate(ab["points"]):
        where = f"ablation.points[{i}] ({pt['name']}).params"
        try:
            if pt["method"].startswith("model_based_"):
                variant = pt["method"][len("model_based_"):]
                mb.resolve_params({**cfg["model_based"][variant], **pt.get("params", {})}, variant)
            elif pt["method"] == "sasa":
                base = sasa.PAPER if s["preset"] == "paper" else sasa.DEFAULTS
                sasa.resolve_params({**s["params"], **pt.get("params", {})}, base)
        except (ValueError, TypeError) as exc:
            out.append(f"{where}: {exc}")
    return out


def realism_test_config(cfg: dict) -> dict:
    """The scene config of the realism test set: `cfg` with `realism_test.sensor` as the sensor's
    realism profile and `realism_test.burial_m` as the scenes' burial (same seeds, so the same
    seabeds, objects and poses as the synthetic scenes)."""
    out = copy.deepcopy(cfg)
    out["sensor"]["realism"] = copy.deepcopy(cfg["realism_test"]["sensor"])
    out["scenes"]["realism"] = {"burial_m": list(cfg["realism_test"]["burial_m"])}
    return out


def realism_effects(cfg: dict) -> dict[str, list[str]]:
    """The effects of the one-at-a-time realism ablation: `realism_ablation.effects`, or when that is
    empty the standard groups (:data:`REALISM_EFFECT_GROUPS`) restricted to the keys `realism_test`
    sets (a group with none of them is left out). Empty when the ablation is disabled."""
    ra = cfg["realism_ablation"]
    if not ra["enabled"]:
        return {}
    if ra["effects"]:
        return {k: list(v) for k, v in ra["effects"].items()}
    rt = cfg["realism_test"]
    out = {}
    for name, keys in REALISM_EFFECT_GROUPS.items():
        on = [k for k in keys if (k == "burial_m" and max(rt["burial_m"]) > 0) or k in rt["sensor"]]
        if on:
            out[name] = on
    return out


def realism_effect_config(cfg: dict, effect: str) -> dict:
    """The scene config of one effect of the realism ablation: `cfg` with only the keys of
    `realism_ablation.effects[effect]` switched on, at their `realism_test` values (`burial_m` stands
    for the burial of `realism_test.burial_m`; every other effect keeps the objects unburied)."""
    keys = realism_effects(cfg)[effect]
    rt = cfg["realism_test"]
    out = copy.deepcopy(cfg)
    sensor = {k: copy.deepcopy(rt["sensor"][k]) for k in keys if k != "burial_m"}
    if sensor:
        out["sensor"]["realism"] = sensor
    else:
        out["sensor"].pop("realism", None)
    out["scenes"]["realism"] = {"burial_m": list(rt["burial_m"]) if "burial_m" in keys else [0.0, 0.0]}
    return out


def load_config(path) -> dict:
    """Read a YAML config file, validate it and fill defaults."""
    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys to values")
    return validate_config(data, source=str(path))
