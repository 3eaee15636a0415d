"""The registries (docs/architecture.md section 3): methods, object classes, plugins, and what the
config derives from them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from conftest import REPO
from sonardet import methods
from sonardet.config import ConfigError, read_schema, validate_config
from sonardet.methods import Method
from sonardet.objects import classes, footprint_radius_m, object_info
from sonardet.plugins import PluginError, load_plugins

CUBE = str(REPO / "tests" / "plugins" / "cube_class.py")
CENTROID = str(REPO / "tests" / "plugins" / "centroid_method.py")


def test_default_methods_come_from_the_registry(default_config):
    names = [m.name for m in methods.configured(default_config)]
    assert names == ["model_based_paper", "model_based_ours", "model_based_paper_tight", "sasa_25", "sasa_50",
                     "sasa_100", "sasa_dr_100"]
    assert [m.name for m in methods.main_methods(default_config)] == [n for n in names if n not in (
        "model_based_paper_tight", "sasa_dr_100")]
    tight = methods.get("model_based_paper_tight", default_config)
    assert tight.group == "ladder" and tight.datasets == ("synthetic",)
    assert tight.settings["params"]["score"] == "tight_fitness" and tight.settings["variant"] == "paper"
    dr = methods.get("sasa_dr_100", default_config)
    assert dr.variant_of == "sasa_100" and dr.settings["params"]["dr_enabled"] is True
    ours = methods.get("model_based_ours", default_config)
    assert ours.runner == "per_scene" and not ours.trained and set(ours.resources) == {"objects", "templates"}
    sasa = methods.get("sasa_50", default_config)
    assert sasa.runner == "per_dataset" and sasa.trained and sasa.fraction == 50 and sasa.resources == ("model",)


def test_methods_that_share_a_run_are_grouped(default_config):
    """`paper` and the ladder's re-ranking of it share their registrations on the synthetic test set;
    `ours`, the per-dataset SASA and a `paper` setting that changes the windows each run alone."""
    on_test = [m for m in methods.configured(default_config) if m.runs_on("synthetic")]
    groups = [[m.name for m in g] for g in methods.shared_runs(on_test)]
    assert groups == [["model_based_paper", "model_based_paper_tight"], ["model_based_ours"]]
    on_dev = [m for m in methods.configured(default_config) if m.runs_on("dev")]
    assert [[m.name for m in g] for g in methods.shared_runs(on_dev)] == [["model_based_paper"], ["model_based_ours"]]
    family = methods.family("model_based")
    paper = methods.get("model_based_paper", default_config)
    wider = paper.with_settings(params={"window_overlap": 0.25})
    assert family.share_key(wider) != family.share_key(paper) is not None
    assert family.share_key(methods.get("model_based_ours", default_config)) is None
    with pytest.raises(ValueError, match="share"):
        family.load_shared([paper, wider], methods.Resources())
    # Per-dataset methods: every SASA model, domain-randomised too, in one job per dataset.
    assert [[m.name for m in g] for g in methods.shared_runs(on_test, runner="per_dataset")] == [
        ["sasa_25", "sasa_50", "sasa_100", "sasa_dr_100"]]
    on_gpu = methods.get("sasa_50", default_config).with_settings(device="cuda")
    assert len(methods.shared_runs([on_gpu, methods.get("sasa_100", default_config)], runner="per_dataset")) == 2
    lone = Method(name="other_100", family="other", runner="per_dataset")  # no share key: a job of its own
    assert [[m.name for m in g] for g in methods.shared_runs(on_test + [lone], runner="per_dataset")] == [
        ["sasa_25", "sasa_50", "sasa_100", "sasa_dr_100"], ["other_100"]]
    with pytest.raises(ValueError, match="runner"):
        methods.shared_runs(on_test, runner="per_tile")


def test_a_method_not_configured_is_still_recognised(default_config):
    m = methods.get("sasa_30", default_config)  # e.g. a model trained elsewhere
    assert m.family == "sasa" and m.fraction == 30
    with pytest.raises(ValueError, match=r"unknown method 'detr_100'.*configured methods: model_based_paper"):
        methods.get("detr_100", default_config)
    with pytest.raises(KeyError, match="unknown method family 'nope'"):
        methods.family("nope")


def test_method_round_trip_and_validation():
    m = Method(name="sasa_25", family="sasa", settings={"params": {"a": 1}}, runner="per_dataset", trained=True,
               fraction=25, resources=("model",), threads=2)
    assert Method.from_dict(json.loads(json.dumps(m.to_dict()))) == m
    assert m.with_settings(params={"b": 2}).settings["params"] == {"a": 1, "b": 2}
    with pytest.raises(ValueError, match="names folders"):
        Method(name="a/b", family="x")
    with pytest.raises(ValueError, match="runner"):
        Method(name="a", family="x", runner="batch")
    with pytest.raises(ValueError, match="training fraction"):
        Method(name="a", family="x", trained=True)
    with pytest.raises(ValueError, match="unknown resources"):
        Method(name="a", family="x", resources=("gpu",))


def test_ablation_point_methods(default_config):
    from sonardet.experiments.ablation import check_points, point_method

    pt = {"name": "p", "method": "sasa", "fraction": 25, "params": {"n_points": 4096}}
    m = point_method(pt, default_config)
    assert m.name == "sasa_25" and m.settings["params"]["n_points"] == 4096 and m.trained
    m = point_method({"name": "q", "method": "model_based_ours", "params": {"n_yaw_init": 4}}, default_config)
    assert m.settings == {"variant": "ours", "params": {"n_yaw_init": 4}}
    bad = check_points([{"name": "x", "method": "nonsense"}, {"name": "y", "method": "sasa", "fraction": 30}],
                       default_config)
    assert any("neither a method nor a method family" in b for b in bad)
    assert any("fraction: 30 is not one of split.fractions" in b for b in bad)


def test_unknown_method_family_section_is_refused():
    with pytest.raises(ConfigError, match=r"methods\.detr: no registered method family"):
        validate_config({"methods": {"detr": {}}})


def test_plugin_method_is_configured_and_runs():
    cfg = validate_config({"plugins": [CENTROID], "methods": {"centroid": {"min_height_m": 0.25}}})
    m = methods.get("centroid", cfg)
    assert m.runner == "per_scene" and m.settings["cls"] == cfg["classes"][0]
    assert "centroid" in [x.name for x in methods.main_methods(cfg)]
    # A flat seabed with one 1 m block: one box around the block.
    g = np.stack(np.meshgrid(np.arange(0, 10, 0.1), np.arange(0, 10, 0.1)), -1).reshape(-1, 2)
    xyz = np.c_[g, np.zeros(len(g))]
    top = (np.abs(g[:, 0] - 5) < 0.5) & (np.abs(g[:, 1] - 3) < 0.5)
    xyz[top, 2] = 1.0
    dets, stats = methods.family("centroid").load(m, methods.Resources())(xyz)
    assert len(dets) == 1 and np.allclose(dets[0]["box"][:2], [5.0, 3.0], atol=0.06)
    assert stats["seconds"]["total"] >= 0
    with pytest.raises(ConfigError, match=r"methods\.centroid\.size: unknown key"):
        validate_config({"plugins": [CENTROID], "methods": {"centroid": {"size": 1}}})


def test_plugin_errors_name_the_entry(tmp_path):
    with pytest.raises(PluginError, match=r"plugins\[0\].*no such file"):
        load_plugins([str(tmp_path / "missing.py")])
    bad = tmp_path / "bad.py"
    bad.write_text("raise RuntimeError('boom')\n")
    with pytest.raises(PluginError, match=r"plugins\[0\].*RuntimeError: boom"):
        load_plugins([str(bad)])
    with pytest.raises(PluginError, match="cannot import module 'no_such_module_xyz'"):
        load_plugins(["no_such_module_xyz"])
    with pytest.raises(ConfigError, match=r"plugins\[0\]"):
        validate_config({"plugins": [str(tmp_path / "missing.py")]})


def test_class_specs_give_schema_and_defaults():
    assert classes.names()[:4] == ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
    schema = read_schema()["properties"]
    assert {k: v["default"] for k, v in schema["objects"]["properties"]["tetrapod_b"]["properties"].items()} == {
        "height_m": 2.08, "mass_kg": 6000, "taper": 0.6}
    assert validate_config({})["objects"]["tetrapod_b"] == {"height_m": 2.08, "mass_kg": 6000, "taper": 0.6}
    assert schema["scenes"]["properties"]["pile_layers"]["default"] == {"reef_ring": 2, "tetrapod_s": 3}
    cfg = validate_config({"objects": {"tetrapod_s": {"height_m": 1.5}}})
    assert cfg["objects"]["tetrapod_s"] == {"height_m": 1.5, "mass_kg": 2000, "taper": 0.6}
    with pytest.raises(ConfigError, match=r"objects\.reef_cone\.wall_m"):
        validate_config({"objects": {"reef_cone": {"wall_m": -1}}})
    with pytest.raises(ConfigError, match=r"classes\[1\]: 'cube' is not a registered class"):
        validate_config({"classes": ["reef_ring", "cube"]})


def test_footprints_come_from_the_meshes(default_config):
    objects = default_config["objects"]
    assert footprint_radius_m("reef_ring", objects) == pytest.approx(1.34, abs=0.01)
    assert footprint_radius_m("reef_cone", objects) == pytest.approx(1.0, abs=0.01)
    # Tetrapods: a down leg's tip reaches furthest; within 2 cm of the full mesh's 1.363 / 0.928 m.
    assert footprint_radius_m("tetrapod_b", objects) == pytest.approx(1.36, abs=0.02)
    assert footprint_radius_m("tetrapod_s", objects) == pytest.approx(0.93, abs=0.02)
    bigger = {**objects, "reef_ring": {**objects["reef_ring"], "outer_diameter_m": 4.0}}
    assert footprint_radius_m("reef_ring", bigger) == pytest.approx(2.0, abs=0.01)


def test_packing_check_uses_the_footprints():
    with pytest.raises(ConfigError, match=r"scenes\.n_objects: up to 300 objects need about") as e:
        validate_config({"scenes": {"n_objects": [250, 300]}})
    assert str(e.value).count("scenes.n_objects") == 1  # each message once


def test_a_plugin_class_leaves_other_configs_alone():
    """Registering a class (a plugin imported earlier in the process) must not change the objects
    section, and so the config hash, of a config that does not use it."""
    before = validate_config({})
    load_plugins([CUBE])
    assert validate_config({}) == before and "concrete_cube" not in before["objects"]


def test_fifth_class_by_one_spec(tmp_path):
    cfg = validate_config({"plugins": [CUBE], "classes": ["reef_ring", "concrete_cube"]})
    assert cfg["objects"]["concrete_cube"] == {"edge_m": 1.2}
    assert cfg["scenes"]["class_mix"]["concrete_cube"] == 0.25
    spec = classes.get("concrete_cube")
    model = classes.build_object("concrete_cube", cfg["objects"])
    assert model.mesh.is_watertight and model.mesh.volume == pytest.approx(1.728)
    assert footprint_radius_m("concrete_cube", cfg["objects"]) == pytest.approx(0.6 * np.sqrt(2), abs=1e-6)
    info = object_info(model, 2400.0)
    assert info.up_axes.shape == (6, 3) and info.tumble["mode"] == "tilts"
    assert spec.metadata()["up_axes"][0] == [0.0, 0.0, 1.0]
    from sonardet.methods.sasa import resolved_params

    m = methods.get("sasa_100", cfg)
    assert resolved_params(m)["symmetry_orders"] == {"reef_ring": 0, "concrete_cube": 4}
    from sonardet.report.style import class_color

    assert class_color("concrete_cube") == "#E69F00" and class_color("reef_ring") == "#0072B2"


def test_object_files_carry_the_spec(tmp_path, built_objects):
    from sonardet.objects import read_object, write_object

    m = built_objects["tetrapod_s"]
    write_object(m, 2400.0, tmp_path / "t.ply", tmp_path / "t.json")
    info = read_object(tmp_path / "t.json")
    assert info.up_axes.shape == (4, 3) and np.allclose(info.up_axes[0], [0, 0, 1])
    assert info.tumble["mode"] == "tilts" and info.tumble["tilts_deg"] == [30.0, 55.0]
    doc = json.loads((tmp_path / "t.json").read_text())
    del doc["up_axes"]
    (tmp_path / "t.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="no up_axes.*rebuild it"):
        read_object(tmp_path / "t.json")
