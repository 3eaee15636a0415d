"""Sensor effects: each realism effect of the simulator is one :class:`Effect` (its config keys with
defaults, units, docs and validation, the stage it acts at, how it is applied), kept in an ordered
registry (:mod:`.registry`). :class:`RealismConfig` (the `sensor.realism` section), the realism
ablation's standard groups (:data:`REALISM_EFFECT_GROUPS`) and the config schema of the realism
keys (:func:`realism_schema`) are derived from it; the realistic scan of :mod:`sonardet.sim.mbes`
runs the effects stage by stage; SASA's domain randomisation uses their point-stage functions.

The built-in effects, in registry (config key) order: footprint (and detection mode), quantisation,
attitude (biases, motion, heave), refraction (surface_sound_speed and svp_bias), outliers,
outer_dropouts, line_offsets, roughness (sensor stages; `sensor.realism`), burial (scene stage;
`scenes.realism`). :mod:`.noise` holds the sensor's own range noise, used by the scan and by domain
randomisation.

The order in which they act in a scan (stage, then `order`): attitude, surface sound speed (ray);
roughness (range); footprint detection, outer dropouts, then the sensor's own dropouts and range
noise, outliers, quantisation (sounding); line offsets, SVP bias (point). The random parts draw from
a child generator spawned from the scan's generator (:func:`child_rng`), so the sensor's own
dropouts and range noise keep their realisation when effects are turned on or off; per-line
quantities come from one fixed set of per-line draws (:func:`draw_lines`).

Adding an effect: one module that builds an :class:`Effect` and calls :func:`register` (in this
package, imported below, or in a plugin listed under the config's `plugins`).
"""

from .base import (
    SCENE_SECTION,
    SENSOR_SECTION,
    STAGES,
    Effect,
    Key,
    LineDraws,
    Reach,
    ScanChunk,
    ScanSetup,
    child_rng,
    draw_lines,
)
from .registry import (
    REALISM_EFFECT_GROUPS,
    EffectGroups,
    RealismConfig,
    effect,
    effect_groups,
    effects,
    pipeline,
    realism_schema,
    register,
    sensor_effects,
    sensor_keys,
    unregister,
)

# The built-in effects register themselves at import, in this (config key) order.
from . import footprint, quantisation, attitude, refraction, outliers, outer_dropouts  # noqa: E402,I001
from . import line_offsets, roughness, burial, noise  # noqa: E402,I001
from .geometry import fan_directions, ping_times_s, swath_margin_m  # noqa: E402

__all__ = [
    "STAGES", "SCENE_SECTION", "SENSOR_SECTION", "Effect", "Key", "Reach", "LineDraws", "ScanSetup", "ScanChunk",
    "child_rng", "draw_lines", "REALISM_EFFECT_GROUPS", "EffectGroups", "RealismConfig", "effect", "effect_groups",
    "effects", "pipeline", "realism_schema", "register", "unregister", "sensor_effects", "sensor_keys",
    "fan_directions", "ping_times_s", "swath_margin_m",
    "footprint", "quantisation", "attitude", "refraction", "outliers", "outer_dropouts", "line_offsets", "roughness",
    "burial", "noise",
]
