"""Constraints between config keys that a JSON schema cannot express; each problem names its key.

`cross_checks` lists the problems that stop a run; `config_warnings` the settings that run but make
the experiment say little (objects too small for the sensor's sounding spacing to see, classes that
never appear), each message naming its key.
"""

from __future__ import annotations

import math

from .. import methods
from ..experiments.ablation import check_points
from ..objects import classes
from ..objects.perturb import check_ranges
from ..sim.mbes import SensorConfig, sounding_spacing_m, survey_lines_per_direction
from .realism import realism_effects

__all__ = ["config_warnings", "cross_checks"]

#: A fan whose soundings are farther apart across track than this share of the smallest object's
#: width cannot sample its shape (a ring's hole, a tetrapod's legs): refused.
MAX_SPACING_FRAC = 0.5
#: More survey lines per direction than this (a very narrow swath) makes scene synthesis slow: warned.
MAX_LINES_PER_DIRECTION = 200


def _range_checks(cfg: dict) -> list[str]:
    out = []
    sc = cfg["scenes"]
    if sc["seabed"]["mean_depth_m"] >= sc["survey"]["transducer_z_m"]:
        out.append(f"scenes.seabed.mean_depth_m: {sc['seabed']['mean_depth_m']} m is not below the transducer "
                   f"(scenes.survey.transducer_z_m = {sc['survey']['transducer_z_m']} m)")
    for key in ("n_objects", "n_rocks", "scatter_fraction", "cone_gap_m", "big_spacing_m", "rock_size_m", "dump_n"):
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


def _object_sizes(cfg: dict) -> dict[str, tuple[float, float]]:
    """Class -> (width (m, twice the footprint radius), height (m)) of the configured classes, from the
    coarse builds of the class specs."""
    return {c: (2.0 * classes.footprint_radius_m(c, cfg["objects"]), classes.height_m(c, cfg["objects"]))
            for c in cfg["classes"]}


def _survey_geometry(cfg: dict) -> tuple[SensorConfig, float, float, float]:
    """(sensor, altitude above the mean seabed (m), across- and along-track sounding spacing (m))."""
    sc = cfg["scenes"]
    sensor = SensorConfig.from_dict({k: v for k, v in cfg["sensor"].items() if k != "realism"})
    altitude = sc["survey"]["transducer_z_m"] - sc["seabed"]["mean_depth_m"]
    across, along = sounding_spacing_m(sensor, altitude, sc["survey"]["overlap"])
    return sensor, altitude, across, along


def _degenerate_checks(cfg: dict) -> list[str]:
    """Settings that leave nothing to detect: scenes without objects, a transducer at or below the top of
    an object, soundings farther apart across track than half the smallest object."""
    sc, out = cfg["scenes"], []
    if sc["n_objects"][1] == 0:
        out.append(f"scenes.n_objects: {sc['n_objects']} puts no object in any scene: there is nothing to train "
                   "on, detect or evaluate (every mAP would be 0); allow at least one object")
    try:
        sizes = _object_sizes(cfg)
    except (ValueError, RuntimeError) as exc:
        return out + [f"objects: {exc}"]
    tallest = max(sizes, key=lambda c: sizes[c][1])
    _, altitude, across, _ = _survey_geometry(cfg)
    if altitude <= sizes[tallest][1]:
        out.append(f"scenes.survey.transducer_z_m: the transducer is {altitude:g} m above the mean seabed "
                   f"(scenes.seabed.mean_depth_m {sc['seabed']['mean_depth_m']:g} m), not above the tallest object "
                   f"({tallest}, {sizes[tallest][1]:.2f} m high): the swath cannot see it whole")
    if cfg["templates"]["altitude_m"] <= sizes[tallest][1]:
        out.append(f"templates.altitude_m: {cfg['templates']['altitude_m']:g} m is not above the tallest object "
                   f"({tallest}, {sizes[tallest][1]:.2f} m high)")
    smallest = min(sizes, key=lambda c: sizes[c][0])
    width = sizes[smallest][0]
    if altitude > 0 and across > MAX_SPACING_FRAC * width:
        sn = cfg["sensor"]
        swath = 2.0 * altitude * math.tan(math.radians(0.5 * sn["swath_deg"]))
        need = math.ceil(swath / (MAX_SPACING_FRAC * width)) + 1
        out.append(f"sensor.n_beams: {sn['n_beams']} beam(s) over {sn['swath_deg']:g} deg put soundings {across:.2f} m "
                   f"apart across track at {altitude:g} m altitude, more than half the smallest object "
                   f"({smallest}, {width:.2f} m wide): objects fall between the beams; use at least {need} beams "
                   "(or a narrower sensor.swath_deg)")
    return out


def config_warnings(cfg: dict) -> list[str]:
    """Settings of a valid config (defaults filled in) that run but make the experiment say little, each
    message naming its key: objects so small for the sounding spacing that fewer soundings than
    scenes.min_points_visible fall on them (flagged invisible, left out of the evaluation), a swath so
    narrow that a scene needs hundreds of survey lines, classes the class mix never draws, ablations
    asking for more scenes than there are development scenes."""
    sc, out = cfg["scenes"], []
    n_dev = cfg["split"]["n_dev"]
    for key in ("ablation", "realism_ablation"):
        if cfg[key]["enabled"] and cfg[key]["n_scenes"] > n_dev:
            out.append(f"{key}.n_scenes: {cfg[key]['n_scenes']} asks for more scenes than the {n_dev} development "
                       f"scenes (split.n_dev); it runs on {n_dev}")
    mix = {c: sc["class_mix"].get(c, 0.0) for c in cfg["classes"]}
    if sum(mix.values()) > 0:
        out += [f"scenes.class_mix.{c}: 0 puts no {c} in any scene; its AP is 0 and lowers every mAP (drop the "
                "class from `classes`, or give it a weight)" for c, w in mix.items() if w <= 0]
    try:
        sizes = _object_sizes(cfg)
        sensor, altitude, across, along = _survey_geometry(cfg)
    except (ValueError, RuntimeError):
        return out  # reported by cross_checks
    smallest = min(sizes, key=lambda c: sizes[c][0])
    width = sizes[smallest][0]
    expected = (width / across) * (width / along) * math.pi / 4.0
    if expected < sc["min_points_visible"]:
        out.append(f"sensor: about {expected:.0f} soundings fall on the smallest object ({smallest}, {width:.2f} m "
                   f"wide; {across:.2f} m across and {along:.3f} m along track at {altitude:g} m altitude), fewer "
                   f"than scenes.min_points_visible ({sc['min_points_visible']}): most objects would be flagged "
                   "invisible and left out of the evaluation; add beams (sensor.n_beams) or lower the speed")
    lines = survey_lines_per_direction(sensor, altitude, sc["survey"]["overlap"], sc["extent_m"])
    if lines > MAX_LINES_PER_DIRECTION:
        out.append(f"sensor.swath_deg: a {sensor.swath_deg:g} deg swath covers a {sc['extent_m'][0]:g} x "
                   f"{sc['extent_m'][1]:g} m scene with {lines} survey lines per direction; scene synthesis time "
                   "grows with the lines")
    return out


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
    if not out:  # the survey geometry needs sane ranges (a seabed below the transducer)
        out += _degenerate_checks(cfg)
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
