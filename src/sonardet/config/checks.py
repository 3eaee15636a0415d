"""Constraints between config keys that a JSON schema cannot express; each problem names its key."""

from __future__ import annotations

import math

from .. import methods
from ..experiments.ablation import check_points
from ..objects import classes
from ..objects.perturb import check_ranges
from .realism import realism_effects

__all__ = ["cross_checks"]


def _range_checks(cfg: dict) -> list[str]:
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
    return out


def _packing_check(cfg: dict) -> list[str]:
    """More objects than fit: footprints (from the class meshes) of the largest count may cover at
    most 60 % of the scene."""
    sc = cfg["scenes"]
    mix = {c: sc["class_mix"].get(c, 0.0) for c in cfg["classes"]}
    total = sum(mix.values())
    if total <= 0:
        return ["scenes.class_mix: no weight on any class of `classes`"]
    try:
        area = sum(w / total * math.pi * classes.footprint_radius_m(c, cfg["objects"]) ** 2 for c, w in mix.items())
    except (ValueError, RuntimeError) as exc:
        return [f"objects: {exc}"]
    ex, ey = sc["extent_m"]
    if sc["n_objects"][1] * area > 0.6 * ex * ey:
        return [f"scenes.n_objects: up to {sc['n_objects'][1]} objects need about {sc['n_objects'][1] * area:.0f} m^2 "
                f"of seabed, more than 60 % of the {ex} x {ey} m scene (scenes.extent_m); lower n_objects or "
                "enlarge the scene"]
    return []


def _ablation_checks(cfg: dict) -> list[str]:
    ab = cfg["ablation"]
    out = check_points(ab["points"], cfg)
    if out:
        return out
    for i, pt in enumerate(ab["points"]):
        try:
            m = methods.family(_point_family(pt, cfg)).ablation_method(pt, cfg)
            methods.family(m.family).check_params(m)
        except (ValueError, TypeError, KeyError) as exc:
            out.append(f"ablation.points[{i}] ({pt['name']}).params: {exc}")
    return out


def _survey_method_checks(cfg: dict) -> list[str]:
    """Each survey's method must be one the registry knows."""
    out = []
    for name, entry in cfg["surveys"].items():
        try:
            methods.get(entry.get("method", "model_based_ours"), cfg)
        except ValueError as exc:
            out.append(f"surveys.{name}.method: {exc}")
    return out


def _point_family(point: dict, cfg: dict) -> str:
    """Family of an ablation point's method: a family name or a method of a family."""
    names = {f.name for f in methods.families()}
    return point["method"] if point["method"] in names else methods.get(point["method"], cfg).family


def _realism_ablation_checks(cfg: dict) -> list[str]:
    """The one-at-a-time realism ablation needs the realism test set, known effect keys that change
    something, and configured methods."""
    ra = cfg["realism_ablation"]
    if not ra["enabled"]:
        return []
    rt = cfg["realism_test"]
    if not rt["enabled"]:
        return ["realism_ablation.enabled: needs realism_test.enabled (the effects take its values)"]
    out = []
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
    names = [m.name for m in methods.configured(cfg)]
    for m in ra["methods"]:
        if m not in names:
            out.append(f"realism_ablation.methods: {m!r} is not a configured method ({sorted(names)})")
    return out


def _class_checks(cfg: dict) -> list[str]:
    return [f"classes[{i}]: {c!r} is not a registered class ({', '.join(classes.names())}); a plugin listed "
            "under `plugins` may register it" for i, c in enumerate(cfg["classes"]) if c not in classes.names()]


def cross_checks(cfg: dict, validate) -> list[str]:
    """Every cross-key problem of a schema-valid, default-filled config. `validate` validates a
    derived config (the realism test set's) the same way."""
    out = _class_checks(cfg)
    if out:
        return out
    out += _range_checks(cfg) + _packing_check(cfg)
    ev = cfg["evaluation"]
    if ev["headline_m"] not in ev["dist_thresholds_m"]:
        out.append(f"evaluation.headline_m: {ev['headline_m']} is not one of evaluation.dist_thresholds_m "
                   f"{ev['dist_thresholds_m']}")
    out += methods.check(cfg)
    names = [m.name for m in methods.configured(cfg)] if not out else []
    if names and ev["reference"] not in names:
        out.append(f"evaluation.reference: {ev['reference']!r} is not a configured method ({', '.join(names)})")
    if not out:
        out += _ablation_checks(cfg) + _survey_method_checks(cfg)
    out += validate(cfg)
    out += _realism_ablation_checks(cfg)
    if cfg["mismatch_test"]["enabled"]:
        out += check_ranges(cfg["mismatch_test"]["perturbations"], cfg["objects"])
    if cfg["split"]["n_test"] >= cfg["scenes"]["n_scenes"]:
        out.append(f"split.n_test: {cfg['split']['n_test']} test scenes leave none of the "
                   f"{cfg['scenes']['n_scenes']} scenes (scenes.n_scenes) for training")
    return out
