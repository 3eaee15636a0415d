"""Config validation: defaults, and bad input that must name the key."""

import subprocess
import sys

import pytest
import yaml

from conftest import REPO
from sonardet.config import ConfigError, read_config, validate_config
from sonardet.seeds import derive_seed


def test_default_config_is_valid_and_complete(default_config):
    assert default_config["classes"] == ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
    assert default_config["objects"]["tetrapod_s"]["height_m"] == 1.42
    assert default_config["sensor"]["swath_deg"] == 130


def test_paper_config_is_valid():
    import copy

    base = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    paper = yaml.safe_load((REPO / "config" / "paper.yaml").read_text())
    merged = copy.deepcopy(base)
    for k, v in paper.items():  # Snakemake merges --configfile sections into the configfile's
        merged[k] = {**merged.get(k, {}), **v} if isinstance(v, dict) else v
    cfg = validate_config(merged)
    assert cfg["sasa"]["preset"] == "study" and not cfg["ablation"]["enabled"] and cfg["sasa"]["seeds"] == 3


def test_partial_section_keeps_defaults():
    cfg = validate_config({"objects": {"tetrapod_s": {"height_m": 1.5}}})
    assert cfg["objects"]["tetrapod_s"] == {"height_m": 1.5, "mass_kg": 2000, "taper": 0.6}


@pytest.mark.parametrize(
    "bad, key",
    [
        ({"classes": ["reef_ring", "submarine"]}, "classes[1]"),
        ({"objects": {"reef_cone": {"height_m": -1.37}}}, "objects.reef_cone.height_m"),
        ({"objects": {"tetrapod_b": {"mass_kg": 0}}}, "objects.tetrapod_b.mass_kg"),
        ({"sensor": {"swath_deg": 190}}, "sensor.swath_deg"),
        ({"sensor": {"n_beams": 0}}, "sensor.n_beams"),
        ({"sensor": {"n_beams": "many"}}, "sensor.n_beams"),
        ({"sensr": {}}, "sensr"),
        ({"templates": {"colour": "red"}}, "templates.colour"),
        ({"model_based": {"ours": {"n_yaw_inits": 2}}}, "model_based.ours"),
        ({"model_based": {"paper": {"window_overlap": 1.5}}}, "model_based.paper"),
        ({"model_based": {"variants": ["fast"]}}, "model_based.variants[0]"),
        ({"sasa": {"params": {"epoch": 3}}}, "sasa.params"),
        ({"sasa": {"params": {"seed": 3}}}, "sasa.params.seed"),
        ({"sasa": {"device": "tpu"}}, "sasa.device"),
        ({"ablation": {"points": [{"name": "a b", "method": "sasa"}]}}, "ablation.points[0]"),
        ({"ablation": {"points": [{"name": "x", "method": "sasa", "fraction": 30}]}}, "ablation.points[0] (x).fraction"),
        ({"ablation": {"points": [{"name": "x", "method": "model_based_ours", "params": {"bogus": 1}}]}},
         "ablation.points[0] (x).params"),
    ],
)
def test_bad_config_names_the_key(bad, key):
    with pytest.raises(ConfigError) as exc:
        validate_config(bad)
    assert key in str(exc.value)


def test_a_missing_config_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="nothere.yaml: no such config file"):
        read_config(tmp_path / "nothere.yaml")


def test_load_config_rejects_non_mapping(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("- just\n- a list\n")
    with pytest.raises(ConfigError, match="c.yaml"):
        read_config(p)


def test_derived_seeds_are_stable_and_distinct():
    assert derive_seed(1, "scene", "s0001") == derive_seed(1, "scene", "s0001")
    assert derive_seed(1, "scene", "s0001") != derive_seed(1, "scene", "s0002")
    assert derive_seed(1, "scene", "s0001") != derive_seed(2, "scene", "s0001")


def test_workflow_refuses_bad_config_before_any_job(tmp_path):
    """A real snakemake dry run with a negative dimension stops with the key in the message."""
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(yaml.safe_dump({"objects": {"reef_ring": {"height_m": -0.75}}}))
    proc = subprocess.run(
        [sys.executable, "-m", "snakemake", "-n", "--configfile", str(cfg), "--directory", str(tmp_path),
         "--snakefile", str(REPO / "Snakefile")],
        capture_output=True, text=True, cwd=REPO,
    )
    assert proc.returncode != 0
    assert "objects.reef_ring.height_m" in proc.stdout + proc.stderr


_RT = {"enabled": True, "sensor": {"range_quantum_m": 0.003, "outlier_prob": 0.001}, "burial_m": [0.0, 0.1]}


@pytest.mark.parametrize(
    "section, key",
    [
        ({"realism_ablation": {"enabled": True}}, "realism_ablation.enabled: needs realism_test.enabled"),
        ({"realism_test": _RT, "realism_ablation": {"enabled": True, "effects": {"roll": ["roll_bias_deg"]}}},
         "realism_ablation.effects.roll: key 'roll_bias_deg' is not set in realism_test.sensor"),
        ({"realism_test": {**_RT, "burial_m": [0.0, 0.0]},
          "realism_ablation": {"enabled": True, "effects": {"b": ["burial_m"]}}},
         "realism_ablation.effects.b: burial_m is [0, 0]"),
        ({"realism_test": _RT, "realism_ablation": {"enabled": True, "methods": ["sasa_dr_100"]}},
         "realism_ablation.methods: 'sasa_dr_100' is not a configured method"),
        ({"domain_randomisation": {"enabled": True, "fractions": [30]}}, "domain_randomisation.fractions: [30]"),
        ({"hybrid_test": {"cell_m": 0}}, "hybrid_test.cell_m"),
    ],
)
def test_test_set_sections_name_the_key(section, key):
    with pytest.raises(ConfigError) as exc:
        validate_config(section)
    assert key in str(exc.value)


def test_realism_effects_default_to_the_groups_realism_test_sets():
    from sonardet.config import REALISM_EFFECT_GROUPS, realism_effect_config, realism_effects

    cfg = validate_config({"realism_test": _RT, "realism_ablation": {"enabled": True}})
    assert realism_effects(cfg) == {"quantisation": ["range_quantum_m"], "outliers": ["outlier_prob"],
                                    "burial": ["burial_m"]}
    one = realism_effect_config(cfg, "outliers")
    assert one["sensor"]["realism"] == {"outlier_prob": 0.001} and one["scenes"]["realism"]["burial_m"] == [0, 0]
    burial = realism_effect_config(cfg, "burial")
    assert "realism" not in burial["sensor"] and burial["scenes"]["realism"]["burial_m"] == [0.0, 0.1]
    # Every key of the sensor's realism profile belongs to exactly one group.
    from sonardet.config import read_schema

    keys = set(read_schema()["properties"]["sensor"]["properties"]["realism"]["properties"])
    grouped = [k for v in REALISM_EFFECT_GROUPS.values() for k in v if k != "burial_m"]
    assert sorted(grouped) == sorted(keys)
