"""The sensor effects registry (sonardet.sim.effects): RealismConfig, the ablation groups and the schema
are derived from it; a registered effect adds a key, a group and a step of the scan; the validation
names `sensor.realism.<key>`; the scan's pipeline order and swath margin are those of before."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sonardet import config as config_module
from sonardet.config import read_schema, realism_effects
from sonardet.sim import effects as fx
from sonardet.sim.effects import REALISM_EFFECT_GROUPS, Effect, Key, RealismConfig
from sonardet.sim.effects.base import non_negative
from sonardet.sim.effects.refraction import steered_angles
from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, straight_line

#: RealismConfig's fields before the registry (order included: it is the order of to_dict()).
FIELDS_BEFORE = [
    "footprint_n_across", "footprint_n_along", "beamwidth_across_deg", "beamwidth_along_deg", "detection",
    "detection_switch_deg", "range_quantum_m", "roll_bias_deg", "roll_bias_sigma_deg", "pitch_bias_deg",
    "pitch_bias_sigma_deg", "roll_amplitude_deg", "roll_period_s", "pitch_amplitude_deg", "pitch_period_s",
    "yaw_amplitude_deg", "yaw_period_s", "heave_amplitude_m", "heave_period_s", "motion_compensated",
    "surface_sound_speed_error_mps", "svp_bias_coeff", "svp_bias_sigma", "outlier_prob", "outlier_magnitude_m",
    "outlier_outer_power", "outer_dropout_prob", "outer_dropout_start_deg", "line_offset_sigma_m",
    "object_roughness_sigma_m"]

#: The realism ablation's groups as config.py listed them before the registry.
GROUPS_BEFORE = {
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


def test_every_sensor_key_is_a_realism_config_field_in_registry_order():
    fields = [f.name for f in dataclasses.fields(RealismConfig)]
    assert fields == FIELDS_BEFORE
    keys = [k.name for e in fx.sensor_effects() for k in e.keys]
    assert fields == keys
    defaults = RealismConfig()
    for e in fx.sensor_effects():
        for k in e.keys:
            assert getattr(defaults, k.name) == k.default and k.doc and k.unit in ("", "m", "deg", "s", "m/s"), k
        assert not e.on(defaults), e.name  # every default leaves its effect off
    assert not defaults.active and not defaults.steers_rays
    scene_keys = [k.name for e in fx.effects("scene") for k in e.keys]
    assert scene_keys == ["burial_m"] and not set(scene_keys) & set(fields)


def test_groups_are_derived_and_config_uses_them():
    assert dict(REALISM_EFFECT_GROUPS) == GROUPS_BEFORE == fx.effect_groups()
    assert list(REALISM_EFFECT_GROUPS) == list(GROUPS_BEFORE)  # the ablation's dataset order
    assert config_module.REALISM_EFFECT_GROUPS is REALISM_EFFECT_GROUPS


def test_schema_realism_keys_are_the_registrys():
    schema = read_schema()["properties"]
    assert schema["sensor"]["properties"]["realism"]["properties"] == fx.realism_schema("sensor")
    assert schema["scenes"]["properties"]["realism"]["properties"] == fx.realism_schema("scenes")


def test_active_and_steers_rays_follow_the_switches():
    assert RealismConfig(footprint_n_across=3).active and not RealismConfig(beamwidth_across_deg=2.0).active
    assert RealismConfig(roll_period_s=1.0).active is False  # a period alone changes nothing
    for key in ("roll_bias_deg", "pitch_bias_sigma_deg", "yaw_amplitude_deg", "heave_amplitude_m",
                "surface_sound_speed_error_mps"):
        cfg = RealismConfig(**{key: 0.1})
        assert cfg.active and cfg.steers_rays, key
    for key in ("range_quantum_m", "svp_bias_coeff", "svp_bias_sigma", "outlier_prob", "outer_dropout_prob",
                "line_offset_sigma_m", "object_roughness_sigma_m"):
        cfg = RealismConfig(**{key: 0.01})
        assert cfg.active and not cfg.steers_rays, key


#: Values that break some check of a key (each key with checks fails on at least one of them).
BAD_VALUES = (-1, -0.5, 0, 0.5, 1.5, 90.0, float("nan"), float("inf"), "peak")


@pytest.mark.parametrize("key", [k for e in fx.sensor_effects() for k in e.keys if k.checks], ids=lambda k: k.name)
def test_validation_messages_name_the_key(key):
    bad = [v for v in BAD_VALUES if _problem(key, v)]
    assert bad, f"no bad value found for {key.name}"
    for v in bad:
        with pytest.raises(ValueError, match=rf"^sensor\.realism\.{key.name} "):
            RealismConfig(**{key.name: v})


def _problem(key, v):
    try:
        return key.problem(v)
    except (TypeError, ValueError, OverflowError):  # e.g. int(inf): not a value this test can use
        return None


def test_combination_check_and_scene_key_messages():
    with pytest.raises(ValueError, match=r"sensor\.realism\.roll_bias_deg and pitch_bias_deg"):
        RealismConfig(pitch_bias_deg=-50.0)
    burial = fx.effect("burial")
    assert burial.section == "scenes.realism"
    assert burial.problems({"burial_m": [0.3, 0.1]}) == [
        "scenes.realism.burial_m must be [min, max] with 0 <= min <= max, got [0.3, 0.1]"]
    with pytest.raises(ValueError, match=r"^scenes\.realism\.burial_m "):
        burial.validate({"burial_m": [-0.1, 0.1]})
    assert burial.on({"burial_m": [0.0, 0.1]}) and not burial.on({"burial_m": [0.0, 0.0]})


def test_pipeline_order_is_the_order_of_the_sensor_model():
    order = [e.name for stage in fx.STAGES[1:] for e in fx.pipeline(stage)]
    assert order == ["attitude", "surface_sound_speed", "roughness", "footprint", "outer_dropouts", "outliers",
                     "quantisation", "line_offsets", "svp_bias"]


def _swath_margin_before(cfg, altitude_m, half_swath_rad, sound_speed_mps):
    """sim.realism.swath_margin_m as it was before the registry (verbatim but for the names)."""
    if cfg is None or not cfg.active:
        return 0.0
    edge0 = float(steered_angles(np.array([half_swath_rad]), cfg.surface_sound_speed_error_mps, sound_speed_mps)[0])
    steer = abs(edge0 - half_swath_rad)
    across = np.deg2rad(abs(cfg.roll_bias_deg) + 4 * cfg.roll_bias_sigma_deg + cfg.roll_amplitude_deg
                        + 0.5 * cfg.beamwidth_across_deg) + steer
    along = np.deg2rad(abs(cfg.pitch_bias_deg) + 4 * cfg.pitch_bias_sigma_deg + cfg.pitch_amplitude_deg
                       + 0.5 * cfg.beamwidth_along_deg)
    depth = altitude_m + cfg.heave_amplitude_m
    edge = min(half_swath_rad + across, np.deg2rad(85.0))
    half_w = depth * np.tan(edge)
    return float(max(half_w - altitude_m * np.tan(half_swath_rad),
                     depth * np.tan(along) + half_w * np.sin(np.deg2rad(cfg.yaw_amplitude_deg))))


def test_swath_margin_from_the_effects_reaches_equals_the_formula_before():
    rng = np.random.default_rng(0)
    for _ in range(50):
        cfg = RealismConfig(roll_bias_deg=float(rng.uniform(-3, 3)), roll_bias_sigma_deg=float(rng.uniform(0, 0.3)),
                            pitch_bias_deg=float(rng.uniform(-3, 3)), roll_amplitude_deg=float(rng.uniform(0, 5)),
                            pitch_amplitude_deg=float(rng.uniform(0, 5)), yaw_amplitude_deg=float(rng.uniform(0, 2)),
                            heave_amplitude_m=float(rng.uniform(0, 0.3)),
                            surface_sound_speed_error_mps=float(rng.uniform(-10, 10)),
                            beamwidth_across_deg=float(rng.uniform(0.3, 2)))
        half = np.deg2rad(float(rng.uniform(40, 75)))
        assert fx.swath_margin_m(cfg, 11.5, half, 1500.0) == _swath_margin_before(cfg, 11.5, half, 1500.0)
    assert fx.swath_margin_m(RealismConfig(), 11.5, 1.0, 1500.0) == 0.0 and fx.swath_margin_m(None, 11.5, 1.0, 1500.0) == 0.0


# --- a plugin effect ------------------------------------------------------------------------------------

def _lift_apply(cfg, setup, chunk, rng):
    chunk.add_dz(np.full(chunk.r.shape, cfg.test_lift_m))


LIFT = Effect(name="test_lift", stage="point", order=85, doc="Every sounding rises by test_lift_m (m).",
              keys=(Key("test_lift_m", 0.0, "m", "lift of every sounding (m)", {"$ref": "#/definitions/nonneg"},
                        (non_negative,)),),
              switches=("test_lift_m",), apply=_lift_apply)


@pytest.fixture
def lift():
    fx.register(LIFT)
    try:
        yield LIFT
    finally:
        fx.unregister(LIFT.name)


def test_a_registered_effect_adds_a_key_a_group_and_a_scan_step(lift):
    names = [f.name for f in dataclasses.fields(RealismConfig)]
    assert names == FIELDS_BEFORE + ["test_lift_m"]
    cfg = RealismConfig.from_config({"test_lift_m": 0.25})
    assert cfg.test_lift_m == 0.25 and cfg.active and not cfg.steers_rays and RealismConfig().test_lift_m == 0.0
    assert cfg.to_dict()["test_lift_m"] == 0.25 and cfg == RealismConfig(test_lift_m=0.25) and hash(cfg)
    with pytest.raises(ValueError, match=r"^sensor\.realism\.test_lift_m must be >= 0"):
        RealismConfig(test_lift_m=-1.0)
    assert REALISM_EFFECT_GROUPS["test_lift"] == ["test_lift_m"]
    assert config_module.REALISM_EFFECT_GROUPS["test_lift"] == ["test_lift_m"]
    assert fx.realism_schema()["test_lift_m"]["default"] == 0.0
    ablation = {"realism_ablation": {"enabled": True, "effects": {}},
                "realism_test": {"sensor": {"test_lift_m": 0.25, "range_quantum_m": 0.01}, "burial_m": [0.0, 0.0]}}
    assert realism_effects(ablation) == {"quantisation": ["range_quantum_m"], "test_lift": ["test_lift_m"]}
    # In the scan it acts at its stage: every sounding 0.25 m higher, nothing else changes.
    flat = RaycastTarget([(np.array([[-60, -60, -11.5], [60, -60, -11.5], [60, 60, -11.5], [-60, 60, -11.5]]),
                           np.array([[0, 1, 2], [0, 2, 3]]))], [-2])
    base = {"n_beams": 64, "range_sigma_m": 0.0, "dropout_prob": 0.0, "grazing_dropout_prob": 0.0}
    plain = SensorConfig(**base)
    traj = straight_line([-1, 0], [1, 0], 0.0, plain, 11.5)
    a = scan(flat, traj, plain, np.random.default_rng(0))
    b = scan(flat, traj, SensorConfig(**base, realism={"test_lift_m": 0.25}), np.random.default_rng(0))
    assert np.array_equal(a.beam, b.beam) and np.array_equal(a.ping, b.ping)
    assert np.allclose(b.xyz[:, 2] - a.xyz[:, 2], 0.25, atol=1e-9) and np.allclose(b.xyz[:, :2], a.xyz[:, :2])


def test_unregistering_restores_the_config(lift):
    fx.unregister(lift.name)
    try:
        assert [f.name for f in dataclasses.fields(RealismConfig)] == FIELDS_BEFORE
        assert "test_lift" not in REALISM_EFFECT_GROUPS
        with pytest.raises(TypeError):
            RealismConfig(test_lift_m=0.1)
    finally:
        fx.register(lift)


def test_registration_rejects_clashes():
    with pytest.raises(ValueError, match="already registered"):
        fx.register(fx.effect("outliers"))
    taken = Effect(name="test_dup", stage="point", doc="", keys=(Key("outlier_prob", 0.0, "", "x"),))
    with pytest.raises(ValueError, match="outlier_prob"):
        fx.register(taken)
    with pytest.raises(ValueError, match="reserved"):
        fx.register(Effect(name="test_res", stage="point", doc="", keys=(Key("active", 0.0, "", "x"),)))
    with pytest.raises(ValueError, match="stage"):
        Effect(name="test_stage", stage="sonar", doc="", keys=())
    assert "test_dup" not in REALISM_EFFECT_GROUPS and [f.name for f in dataclasses.fields(RealismConfig)] == FIELDS_BEFORE
