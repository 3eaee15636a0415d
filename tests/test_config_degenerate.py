"""Configs that run but cannot give a meaningful result are refused or warned about, naming the key,
each message once: too few beams for the objects, no objects, a transducer at the height of the
objects, a class the mix never draws, a swath so narrow that scenes need hundreds of lines."""

from __future__ import annotations

import warnings

import pytest

from sonardet.config import ConfigError, ConfigWarning, config_warnings, validate_config


def problems(cfg: dict) -> str:
    with pytest.raises(ConfigError) as exc:
        validate_config(cfg)
    return str(exc.value)


def test_one_beam_is_refused_naming_the_key_and_a_fix():
    msg = problems({"sensor": {"n_beams": 1}})
    assert "sensor.n_beams: 1 beam(s) over 130 deg put soundings" in msg and "use at least" in msg
    assert msg.count("sensor.n_beams") == 1


def test_the_default_and_smoke_sensors_pass(default_config, smoke_config):
    assert default_config["sensor"]["n_beams"] == 512 and smoke_config["sensor"]["n_beams"] == 128
    assert config_warnings(default_config) == [] and config_warnings(smoke_config) == []


def test_zero_objects_is_refused_once():
    msg = problems({"scenes": {"n_objects": [0, 0]}, "realism_test": {"enabled": True}})
    assert msg.count("scenes.n_objects: [0, 0] puts no object in any scene") == 1
    validate_config({"scenes": {"n_objects": [0, 3]}})  # some empty scenes are fine


def test_a_transducer_among_the_objects_is_refused():
    msg = problems({"scenes": {"survey": {"transducer_z_m": -10.0}}})
    assert "scenes.survey.transducer_z_m: the transducer is 1.5 m above the mean seabed" in msg
    assert "tetrapod_b" in msg
    assert "templates.altitude_m: 1 m is not above the tallest object" in problems({"templates": {"altitude_m": 1.0}})


def test_too_many_objects_is_reported_once():
    msg = problems({"scenes": {"n_objects": [500, 600]}, "realism_test": {"enabled": True}})
    assert msg.count("scenes.n_objects: up to 600 objects") == 1


@pytest.mark.parametrize("cfg, key", [
    ({"scenes": {"class_mix": {"reef_ring": 0}}}, "scenes.class_mix.reef_ring: 0 puts no reef_ring in any scene"),
    ({"sensor": {"swath_deg": 1.0}}, "sensor.swath_deg: a 1 deg swath covers a 40 x 40 m scene with"),
    ({"sensor": {"n_beams": 64, "speed_mps": 40.0}, "scenes": {"min_points_visible": 60}},
     "sensor: about"),
    ({"ablation": {"enabled": True, "n_scenes": 50}}, "ablation.n_scenes: 50 asks for more scenes than the 10"),
])
def test_weak_settings_are_warned_about_once_per_validation(cfg, key):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        validate_config(cfg)
    msgs = [str(w.message) for w in caught if issubclass(w.category, ConfigWarning)]
    assert len(msgs) == 1 and key in msgs[0], msgs
