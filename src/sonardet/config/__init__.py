"""Workflow configuration (the top layer: imported by the workflow and the CLI only): validation
against the JSON schema, defaults, the derived realism configs.

The schema (`config/schema.yaml`, shipped in the package as `sonardet/data/schema.yaml`, completed
from the class registry by :mod:`.schema`) documents every key with units and default. Validation
first imports the config's `plugins` (they may register classes, methods, effects), then rejects
unknown keys and wrong types or ranges with a message that names the key path, so a bad config
stops the run before any job starts.
"""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import jsonschema
import yaml

from ..objects import classes
from ..plugins import PluginError, load_plugins
from .checks import config_warnings, cross_checks
from .realism import (
    REALISM_EFFECT_GROUPS,
    mismatch_test_config,
    realism_effect_config,
    realism_effects,
    realism_test_config,
)
from .schema import read_schema

__all__ = ["REALISM_EFFECT_GROUPS", "ConfigError", "ConfigWarning", "config_warnings", "mismatch_test_config",
           "read_config", "read_schema", "realism_effect_config",
           "realism_effects", "realism_test_config", "validate_config"]


class ConfigError(ValueError):
    """A configuration value is missing, unknown or out of range; the message names the key."""


class ConfigWarning(UserWarning):
    """A configuration that runs but makes the experiment say little; the message names the key."""


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


def validate_config(config: dict, source: str = "config", warn: bool = True) -> dict:
    """Validate `config` against the schema and return a copy with every default filled in.

    Imports the config's `plugins` first. Raises ConfigError listing every offending key (dotted
    path) with the reason and the source. With `warn`, each of `config_warnings` (settings that run but
    make the experiment say little, e.g. objects too small for the sounding spacing) is issued once as
    a :class:`ConfigWarning` (``warnings.warn``) naming the source and the key.
    """
    try:
        load_plugins(dict(config).get("plugins") or [])
    except PluginError as exc:
        raise ConfigError(f"invalid configuration ({source}):\n  - {exc}") from None
    schema = read_schema()
    cfg = _fill_defaults(copy.deepcopy(dict(config)), schema, schema)
    validator = jsonschema.Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(cfg), key=lambda e: list(map(str, e.absolute_path)))
    problems = [_describe(e) for e in errors]
    if not problems:
        _complete(cfg)
        problems = cross_checks(cfg, _realism_test_problems)
    if problems:
        lines = "\n".join(f"  - {p}" for p in dict.fromkeys(problems))
        raise ConfigError(f"invalid configuration ({source}):\n{lines}\nFix these keys; see config/schema.yaml.")
    if warn:
        for msg in dict.fromkeys(config_warnings(cfg)):
            warnings.warn(ConfigWarning(f"configuration ({source}): {msg}"), stacklevel=2)
    return cfg


def _complete(cfg: dict) -> None:
    """Defaults that depend on other keys: the parameters (objects.{cls}) and the class mix of the
    configured classes, from their specs."""
    mix = cfg["scenes"]["class_mix"]
    for c in cfg["classes"]:
        if c in classes.names():
            cfg["objects"][c] = {**classes.get(c).defaults(), **cfg["objects"].get(c, {})}
            mix.setdefault(c, classes.get(c).mix_weight)


def _realism_test_problems(cfg: dict) -> list[str]:
    """The realism test set's scene config is validated like any config; its problems are named by
    the realism_test keys."""
    if not cfg["realism_test"]["enabled"]:
        return []
    derived = realism_test_config(cfg)
    derived["realism_test"] = {"enabled": False}
    derived["realism_ablation"] = {"enabled": False}
    try:
        validate_config(derived, source="realism_test", warn=False)
    except ConfigError as exc:
        return [line[4:].replace("sensor.realism", "realism_test.sensor")
                .replace("scenes.realism.burial_m", "realism_test.burial_m")
                for line in str(exc).splitlines() if line.startswith("  - ")]
    return []


def read_config(path) -> dict:
    """Read a YAML config file, validate it and fill defaults. A missing file, invalid YAML or a bad
    value raises ConfigError naming the file (and the key)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: no such config file (the default experiment is config/config.yaml in the "
                          "workflow folder)")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys to values")
    return validate_config(data, source=str(path))
