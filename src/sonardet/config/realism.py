"""Scene configs derived from the realism sections: the realism test set (`realism_test`) and the
one-at-a-time realism ablation (`realism_ablation`)."""

from __future__ import annotations

import copy

__all__ = ["REALISM_EFFECT_GROUPS", "realism_effect_config", "realism_effects", "realism_test_config"]


def realism_test_config(cfg: dict) -> dict:
    """The scene config of the realism test set: `cfg` with `realism_test.sensor` as the sensor's
    realism profile and `realism_test.burial_m` as the scenes' burial (same seeds, so the same
    seabeds, objects and poses as the synthetic scenes)."""
    out = copy.deepcopy(cfg)
    out["sensor"]["realism"] = copy.deepcopy(cfg["realism_test"]["sensor"])
    out["scenes"]["realism"] = {"burial_m": list(cfg["realism_test"]["burial_m"])}
    return out


#: The standard effect groups of the realism ablation: effect -> keys of `realism_test.sensor` (or
#: `burial_m`) that together make one physical effect.
REALISM_EFFECT_GROUPS = {
    "footprint": ["footprint_n_across", "footprint_n_along", "beamwidth_across_deg", "beamwidth_along_deg",
                  "detection", "detection_switch_deg"],
    "quantisation": ["range_quantum_m"],
    "attitude": ["roll_bias_deg", "roll_bias_sigma_deg", "pitch_bias_deg", "pitch_bias_sigma_deg",
                 "roll_amplitude_deg", "roll_period_s", "pitch_amplitude_deg", "pitch_period_s",
                 "yaw_amplitude_deg", "yaw_period_s", "heave_amplitude_m", "heave_period_s", "motion_compensated"],
    "refraction": ["surface_sound_speed_error_mps", "svp_bias_coeff", "svp_bias_sigma"],
    "outliers": ["outlier_prob", "outlier_magnitude_m", "outlier_outer_power"],
    "outer_dropouts": ["outer_dropout_prob", "outer_dropout_start_deg"],
    "line_offsets": ["line_offset_sigma_m"],
    "roughness": ["object_roughness_sigma_m"],
    "burial": ["burial_m"],
}


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
