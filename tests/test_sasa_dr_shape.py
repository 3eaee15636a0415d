"""SASA domain randomisation, effect 9 (``dr_shape_*``): objects thicker or thinner than their models
and fouled, moved along their upward surface normals; off by default."""

from __future__ import annotations

import numpy as np
import pytest
from test_sasa_domain_randomisation import FOUR, OFF
from test_sasa_model import TINY, make_scene

from sonardet.detect.sasa import resolve_params
from sonardet.detect.sasa.data import (
    domain_randomise,
    dr_shape_offsets,
    prepare_scene,
    upward_normals,
)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return prepare_scene(make_scene(tmp_path_factory.mktemp("shape"), "sh", 7, FOUR), resolve_params(TINY))


def _params(**over):
    return resolve_params({**TINY, **OFF, "n_points": 1024, **over})


def _grid(n=15):
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    return u.ravel(), v.ravel()


def test_normals_of_a_tilted_plane_point_up():
    u, v = _grid()
    normal = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    a = np.cross(normal, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(normal, a)
    pts = u[:, None] * a + v[:, None] * b
    n = upward_normals(pts)
    assert np.allclose(n, normal, atol=1e-6)
    assert np.allclose(upward_normals(pts[:2]), [0.0, 0.0, 1.0])  # too few points: up


def test_a_top_face_moves_by_the_offset_and_a_wall_by_the_shell_only():
    u, v = _grid()
    top = np.c_[u, v, np.full(len(u), 1.0)]
    d = dr_shape_offsets(top, -0.05, 0.0, np.zeros(3), 0.0)
    assert np.allclose(d, [0.0, 0.0, -0.05])  # thinner: the seen top goes down
    wall = np.c_[u, np.zeros(len(u)), v]
    assert np.allclose(dr_shape_offsets(wall, 0.1, 0.0, np.zeros(3), 0.0), 0.0)
    # the fouling shell: 0.5 + 0.5 sin(k . p + phase) of its thickness, always outward (up)
    k = np.array([2 * np.pi, 0.0, 0.0])
    d = dr_shape_offsets(top, 0.0, 0.04, k, 0.0)
    assert np.allclose(d[:, 2], 0.04 * (0.5 + 0.5 * np.sin(2 * np.pi * top[:, 0])))
    assert d[:, 2].min() >= 0.0 and d[:, 2].max() == pytest.approx(0.04, rel=0.05)


def test_objects_are_reshaped_within_their_class_tolerance(scene):
    p = _params(dr_shape_prob=1.0, dr_shape_fouling_m=[0.0, 0.0])
    d = domain_randomise(scene, p, np.random.default_rng(3))
    diff = d.xyz.astype(np.float64) - scene.xyz[d.source]
    obj = d.label >= 0
    assert np.array_equal(diff[~obj], np.zeros_like(diff[~obj]))  # the seabed is untouched
    assert np.abs(diff[obj]).max() > 0.01
    half = np.array([p["dr_shape_half_thickness_m"][FOUR[c]] for c in scene.cls])
    off = d.draws["shape_offset_m"]
    assert np.all(np.abs(off) <= 0.35 * half + 1e-12) and np.any(off != 0)
    # every object point moved by at most its object's offset, along a unit normal
    idx = {oid: k for k, oid in enumerate(scene.obj_id)}
    lim = np.array([abs(off[idx[lab]]) for lab in d.label[obj]])
    assert np.all(np.linalg.norm(diff[obj], axis=1) <= lim + 1e-5)
    assert np.allclose(d.height.astype(np.float64) - scene.height[d.source], diff[:, 2], atol=2e-5)
    assert np.array_equal(d.boxes, scene.boxes)  # the label is the object, not its model


def test_off_by_default_and_at_probability_zero(scene):
    assert resolve_params({})["dr_shape_prob"] == 0.0
    d = domain_randomise(scene, _params(), np.random.default_rng(3))
    assert np.array_equal(d.xyz, scene.xyz[d.source].astype(np.float32))
    assert not np.any(d.draws["shape_offset_m"])


def test_shape_parameters_are_validated():
    with pytest.raises(ValueError, match="dr_shape_prob"):
        resolve_params({"dr_shape_prob": 1.5})
    with pytest.raises(ValueError, match="dr_shape_offset_frac"):
        resolve_params({"dr_shape_offset_frac": 1.0})
    three = {"reef_ring": 0.045, "reef_cone": 0.075, "tetrapod_s": 0.31}
    resolve_params({"dr_shape_half_thickness_m": three})  # not needed while the effect is off
    with pytest.raises(ValueError, match="dr_shape_half_thickness_m.*missing: tetrapod_b"):
        resolve_params({"dr_shape_half_thickness_m": three, "dr_shape_prob": 0.5})
    with pytest.raises(ValueError, match="dr_shape_half_thickness_m"):
        resolve_params({"dr_shape_half_thickness_m": {**three, "tetrapod_b": -0.1}})
    with pytest.raises(ValueError, match="dr_shape_fouling_m"):
        resolve_params({"dr_shape_fouling_m": [0.05, 0.0]})
