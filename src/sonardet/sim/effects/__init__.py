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

Adding an effect: one module that builds an :class:`Effect`; a plugin (listed under the config's
`plugins`) calls :func:`register` with it, a built-in one is added to :data:`BUILTIN` below.
"""

from . import (
    attitude,
    burial,
    footprint,
    line_offsets,
    noise,
    outer_dropouts,
    outliers,
    quantisation,
    refraction,
    roughness,
)
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
from .geometry import fan_directions, ping_times_s, swath_margin_m
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

#: The built-in effects in registry order: the order of RealismConfig's fields, of the schema's
#: realism keys and of the realism ablation's groups (not the order in which they act: see pipeline).
BUILTIN = (footprint.FOOTPRINT, quantisation.QUANTISATION, attitude.ATTITUDE, refraction.SURFACE_SOUND_SPEED,
           refraction.SVP_BIAS, outliers.OUTLIERS, outer_dropouts.OUTER_DROPOUTS, line_offsets.LINE_OFFSETS,
           roughness.ROUGHNESS, burial.BURIAL)
for _effect in BUILTIN:
    register(_effect)

__all__ = [
    "BUILTIN",
    "REALISM_EFFECT_GROUPS",
    "SCENE_SECTION",
    "SENSOR_SECTION",
    "STAGES",
    "Effect",
    "EffectGroups",
    "Key",
    "LineDraws",
    "Reach",
    "RealismConfig",
    "ScanChunk",
    "ScanSetup",
    "attitude",
    "burial",
    "child_rng",
    "draw_lines",
    "effect",
    "effect_groups",
    "effects",
    "fan_directions",
    "footprint",
    "line_offsets",
    "noise",
    "outer_dropouts",
    "outliers",
    "ping_times_s",
    "pipeline",
    "quantisation",
    "realism_schema",
    "refraction",
    "register",
    "roughness",
    "sensor_effects",
    "sensor_keys",
    "swath_margin_m",
    "unregister",
]
