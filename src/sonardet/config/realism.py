"""Scene configs derived from the realism sections: the realism test set (`realism_test`) and the
one-at-a-time realism ablation (`realism_ablation`)."""

from __future__ import annotations

import copy

from ..sim.effects import REALISM_EFFECT_GROUPS

__all__ = ["REALISM_EFFECT_GROUPS", "mismatch_test_config", "realism_effect_config", "realism_effects",
           "realism_test_config"]


def mismatch_test_config(cfg: dict) -> dict:
    """The scene config of the model-mismatch test set: `cfg` with each object's geometry perturbed by
    `mismatch_test.perturbations` and the objects buried by its `burial_m` (same seeds, so the same
    seabeds and layouts as the synthetic scenes; the physics settles the new shapes)."""
    out = copy.deepcopy(cfg)
    per = copy.deepcopy(cfg["mismatch_test"]["perturbations"])
    out["scenes"]["mismatch"] = {"perturbations": per}
    out["scenes"]["realism"] = {"burial_m": list(per["burial_m"])}
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
