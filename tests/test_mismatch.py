"""The model-mismatch test set: per-object perturbed geometry (sonardet.objects.perturb), its scenes
(sonardet.sim.scene with scenes.mismatch) and the per-perturbation breakdown (sonardet.eval.compare)."""

from __future__ import annotations

import numpy as np
import pytest

from sonardet.config import ConfigError, mismatch_test_config, validate_config
from sonardet.eval.compare import perturbation_breakdown
from sonardet.objects import object_info
from sonardet.objects.perturb import DEFAULT_RANGES, check_ranges, draw_perturbation, foul, perturbed_object


def _base(built_objects, cls, cfg):
    return object_info(built_objects[cls], cfg["objects"]["density_kg_m3"])


def test_defaults_agree_with_the_schema(default_config):
    cfg = validate_config({"mismatch_test": {"enabled": True}})
    assert cfg["mismatch_test"]["perturbations"] == DEFAULT_RANGES
    assert check_ranges(DEFAULT_RANGES, default_config["objects"]) == []


@pytest.mark.parametrize("bad, key", [
    ({"leg_scale": [0.0, 1.2]}, "mismatch_test.perturbations.leg_scale"),
    ({"broken_max_frac": 0.95}, "mismatch_test.perturbations.broken_max_frac"),
    ({"ring_wall_scale": [0.7, 9.0]}, "mismatch_test.perturbations.ring_wall_scale"),
    ({"cone_top_scale": [0.3, 1.0]}, "mismatch_test.perturbations.cone_top_scale"),
    ({"fouling_m": [0.05, 0.01]}, "mismatch_test.perturbations.fouling_m"),
])
def test_ranges_that_make_invalid_meshes_are_refused(bad, key):
    with pytest.raises(ConfigError) as exc:
        validate_config({"mismatch_test": {"enabled": True, "perturbations": bad}})
    assert key in str(exc.value)


def test_tetrapod_legs_scale_at_the_same_height(built_objects, default_config):
    base = _base(built_objects, "tetrapod_b", default_config)
    thin = {"fouling_m": 0.0, "fouling_seed": 0, "leg_scale": 0.65, "broken_leg": None, "broken_frac": 0.0,
            "rounded": False}
    thick = {**thin, "leg_scale": 1.35}
    a = perturbed_object("tetrapod_b", thin, default_config["objects"], base)
    b = perturbed_object("tetrapod_b", thick, default_config["objects"], base)
    assert a.extents_m[2] == pytest.approx(2.08, abs=0.02) and b.extents_m[2] == pytest.approx(2.08, abs=0.02)
    assert a.volume_m3 < 0.6 * base.volume_m3 < base.volume_m3 < b.volume_m3
    broken = perturbed_object("tetrapod_b", {**thin, "leg_scale": 1.0, "broken_leg": 2, "broken_frac": 0.25},
                              default_config["objects"], base)
    assert broken.volume_m3 < base.volume_m3 and a.symmetry_order == 3


def test_ring_and_cone_variants(built_objects, default_config):
    ring = _base(built_objects, "reef_ring", default_config)
    no_ribs = perturbed_object("reef_ring", {"fouling_m": 0.0, "fouling_seed": 0, "n_ribs": 0, "wall_scale": 1.3},
                               default_config["objects"], ring)
    assert no_ribs.extents_m[0] == pytest.approx(2.68, abs=0.01) and no_ribs.volume_m3 > 0.9 * ring.volume_m3
    cone = _base(built_objects, "reef_cone", default_config)
    wide = perturbed_object("reef_cone", {"fouling_m": 0.0, "fouling_seed": 0, "top_scale": 1.3, "n_holes": 20,
                                          "hole_seed": 11}, default_config["objects"], cone)
    assert wide.mesh.is_watertight and wide.volume_m3 > cone.volume_m3  # a wider top, fewer holes


def test_fouling_shell_is_uneven_and_bounded(built_objects):
    mesh = built_objects["reef_cone"].mesh
    fouled = foul(mesh, 0.05, seed=3)
    grow = fouled.extents - mesh.extents
    assert (grow > 0.0).all() and (grow <= 2 * 0.05 + 1e-9).all()
    assert foul(mesh, 0.0, seed=3) is mesh


def test_draws_are_seeded_and_class_specific():
    a = draw_perturbation("tetrapod_s", DEFAULT_RANGES, np.random.default_rng(1))
    assert a == draw_perturbation("tetrapod_s", DEFAULT_RANGES, np.random.default_rng(1))
    assert 0.65 <= a["leg_scale"] <= 1.35 and 0.0 <= a["fouling_m"] <= 0.05
    assert "n_ribs" in draw_perturbation("reef_ring", DEFAULT_RANGES, np.random.default_rng(1))
    assert "leg_scale" not in draw_perturbation("reef_cone", DEFAULT_RANGES, np.random.default_rng(1))


@pytest.mark.slow
def test_a_mismatch_scene_records_its_perturbations(built_objects, default_config):
    from sonardet.sim.scene import simulate_scene

    cfg = validate_config({"classes": ["reef_cone", "tetrapod_s"], "mismatch_test": {"enabled": True},
                           "scenes": {"n_scenes": 2, "extent_m": [12, 12], "n_objects": [3, 3], "n_rocks": [0, 0],
                                      "scatter_fraction": [1.0, 1.0]},
                           "sensor": {"n_beams": 128}, "split": {"n_test": 1, "n_dev": 1}})
    objects = {c: _base(built_objects, c, default_config) for c in cfg["classes"]}
    scene = simulate_scene("s0000", mismatch_test_config(cfg), objects)
    objs = scene.meta["objects"]
    assert objs and all("perturbation" in o and "burial_m" in o for o in objs)
    plain = simulate_scene("s0000", cfg, objects)
    assert [o["cls"] for o in plain.meta["objects"]] == [o["cls"] for o in objs]  # the same layout


def test_breakdown_counts_only_the_bin():
    box = [0.0, 0.0, 0.0, 1, 1, 1, 0]
    gt = {"s": [{"cls": "a", "box": box, "perturbation": {"leg_scale": 0.7}, "burial_m": 0.0},
                {"cls": "a", "box": [5.0, 0, 0, 1, 1, 1, 0], "perturbation": {"leg_scale": 1.3}, "burial_m": 0.0}]}
    dets = {"m": {"s": [{"cls": "a", "box": box, "score": 0.9}]}}  # finds the thin one only
    ev = {"headline_m": 0.5, "min_recall": 0.1, "min_precision": 0.1}
    out = perturbation_breakdown(gt, dets, ["a"], ev)
    assert out["leg scale 0.65-0.85"]["methods"]["m"] == pytest.approx(1.0)
    assert out["leg scale 1.15-1.35"]["methods"]["m"] == pytest.approx(0.0)
    assert out["leg scale 0.65-0.85"]["n_objects"] == 1 and "fouling 0-2 cm" not in out
