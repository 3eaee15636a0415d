"""SASA domain randomisation (``dr_*`` parameters): off = the code path and batches of before; each
effect does what it claims, measurably; determinism; a tiny training run with it on.

Scenes are the tiny synthetic ones of test_sasa_model.py (a noisy, gently sloping seabed plus the
visible faces of class-sized boxes), so the tests need neither the simulator nor results/.
"""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest
import torch
from test_sasa_model import TINY, make_scene

from sonardet.detect.sasa import resolve_params, train
from sonardet.detect.sasa.data import (
    _ground_model,
    augment,
    collate,
    domain_randomise,
    dr_density_weight,
    dr_z_field,
    ground_height,
    prepare_scene,
    sample_points,
    weighted_sample,
)
from sonardet.geometry import points_in_box

pytestmark = pytest.mark.usefixtures("one_torch_thread")

tr = importlib.import_module("sonardet.detect.sasa.trainer")  # the module (the package exports train())

#: Every effect off (zero ranges): a test turns on only the one it checks.
OFF = {
    "dr_enabled": True,
    "dr_range_noise_m": [0.0, 0.0],
    "dr_tilt_deg": [0.0, 0.0],
    "dr_smile_coeff": [0.0, 0.0],
    "dr_heave_m": [0.0, 0.0],
    "dr_line_offset_m": [0.0, 0.0],
    "dr_roughness_m": [0.0, 0.0],
    "dr_burial_prob": 0.0,
    "dr_outlier_frac": [0.0, 0.0],
    "dr_leak_patches": [0, 0],
    "dr_dropout_blobs": [0, 0],
    "dr_density_contrast": [1.0, 1.0],
}
FOUR = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]


@pytest.fixture
def scene(tmp_path):
    """A prepared tiny scene with all four classes (~1.4k kept points)."""
    p = resolve_params(TINY)
    return prepare_scene(make_scene(tmp_path, "dr", 7, FOUR), p)


def _params(**over):
    return resolve_params({**TINY, **OFF, **over})


def _real(d):
    """Mask of the output points that are scene points (not spikes or leaked seabed)."""
    return d.source >= 0


# ---------------------------------------------------------------------------------------------------
# off: nothing changes
# ---------------------------------------------------------------------------------------------------

def _make_batch_before_dr(scenes, params, rng, device, train_aug):
    """``trainer._make_batch`` as it was before domain randomisation (verbatim)."""
    items = []
    for s in scenes:
        idx = sample_points(len(s.xyz), int(params["n_points"]), rng, s.scene_id)
        xyz, h, lab = s.xyz[idx], s.height[idx], s.label[idx]
        boxes = s.boxes
        if train_aug:
            xyz, h, boxes = augment(xyz, h, lab, boxes, s.cls, s.obj_id, params, rng, s.axis)
        items.append((xyz, h, boxes, s.cls))
    return collate(items, device)


def _ground_height_before(xyz, cell_m):
    """``data.ground_height`` as it was before the ground grid was split out (verbatim)."""
    from scipy import ndimage

    xy = xyz[:, :2].astype(np.float64)
    lo = xy.min(axis=0)
    ij = np.floor((xy - lo) / cell_m).astype(np.int64)
    nx, ny = (ij.max(axis=0) + 1).tolist()
    grid = np.full((nx, ny), np.inf)
    np.minimum.at(grid, (ij[:, 0], ij[:, 1]), xyz[:, 2].astype(np.float64))
    empty = ~np.isfinite(grid)
    if empty.any():
        _, idx = ndimage.distance_transform_edt(empty, return_distances=True, return_indices=True)
        grid = grid[tuple(idx)]
    u = (xy - lo) / cell_m - 0.5
    return ndimage.map_coordinates(grid, [u[:, 0], u[:, 1]], order=1, mode="nearest")


def test_disabled_is_off_by_default_and_batches_are_identical(tmp_path, monkeypatch):
    p = resolve_params(TINY)
    assert p["dr_enabled"] is False and resolve_params({})["dr_enabled"] is False
    paths = [make_scene(tmp_path, f"i{i}", i, c) for i, c in enumerate((FOUR[:2], FOUR[2:]))]
    scenes = [prepare_scene(q, p) for q in paths]

    def no_dr(*a, **k):
        raise AssertionError("domain_randomise ran with dr_enabled False")

    monkeypatch.setattr(tr, "domain_randomise", no_dr)
    for aug in (False, True):
        for seed in range(3):
            r_new, r_old = np.random.default_rng(seed), np.random.default_rng(seed)
            new = tr._make_batch(scenes, p, r_new, "cpu", aug)
            old = _make_batch_before_dr(scenes, p, r_old, "cpu", aug)
            assert new.keys() == old.keys()
            assert all(torch.equal(new[k], old[k]) for k in new)
            assert r_new.bit_generator.state == r_old.bit_generator.state  # no extra draws


def test_ground_filter_unchanged_by_the_ground_grid_refactor(scene, tmp_path):
    raw = np.load(make_scene(tmp_path, "g", 3, FOUR))["xyz"]
    assert np.array_equal(ground_height(raw, 2.0), _ground_height_before(raw, 2.0))
    assert np.array_equal(ground_height(raw, 0.7), _ground_height_before(raw, 0.7))
    gg = scene.meta["ground_grid"]  # the grid kept for domain randomisation, in the local frame
    z = _ground_model(scene, 2.0)[0](scene.xyz[:, :2].astype(np.float64))
    assert np.allclose(z, scene.xyz[:, 2] - scene.height, atol=1e-4) and gg["cell_m"] == 2.0


def test_disabled_training_is_identical_to_the_code_before(tmp_path, monkeypatch):
    """The whole training (weights, loss history) with dr off equals a run whose batches come from
    the pre-DR _make_batch, and its checkpoint settings carry no dr_ key (old checkpoints resume)."""
    paths = [make_scene(tmp_path, f"t{i}", i, c) for i, c in enumerate((FOUR[:2], FOUR[2:]))]
    params = {**TINY, "epochs": 2, "batch_size": 2}
    a = train(paths, [], params, tmp_path / "a", resume=False)
    real = tr._make_batch

    def before(scenes, prm, rng, device, train_aug, dr_rng=None):
        assert dr_rng is None
        return _make_batch_before_dr(scenes, prm, rng, device, train_aug)

    monkeypatch.setattr(tr, "_make_batch", before)
    b = train(paths, [], params, tmp_path / "b", resume=False)
    monkeypatch.setattr(tr, "_make_batch", real)
    sa = torch.load(tmp_path / "a" / "model.pt", weights_only=False)
    sb = torch.load(tmp_path / "b" / "model.pt", weights_only=False)
    assert all(torch.equal(sa["state_dict"][k], sb["state_dict"][k]) for k in sa["state_dict"])
    assert a["final_loss"]["loss"] == b["final_loss"]["loss"]
    assert not any(k.startswith("dr_") for k in sa["settings"])
    on = tr._checkpoint_settings(resolve_params({"dr_enabled": True}), ["x"])
    assert on["dr_enabled"] is True and "dr_range_noise_m" in on


# ---------------------------------------------------------------------------------------------------
# each effect
# ---------------------------------------------------------------------------------------------------

def test_range_noise_sigma_in_range_on_z_and_height(scene):
    p = _params(dr_range_noise_m=[0.02, 0.04], n_points=1024)
    sigmas = []
    for seed in range(6):
        d = domain_randomise(scene, p, np.random.default_rng(seed))
        m = _real(d)
        assert m.all()  # nothing generated with the other effects off
        dz = d.xyz[:, 2].astype(np.float64) - scene.xyz[d.source, 2]
        dh = d.height.astype(np.float64) - scene.height[d.source]
        s = d.draws["noise_sigma_m"]
        assert 0.02 <= s <= 0.04
        assert np.allclose(dz, dh, atol=2e-5)  # the same noise on z and on the height feature
        assert abs(dz.std() - s) < 0.1 * s and abs(dz.mean()) < 3 * s / math.sqrt(len(dz))
        assert np.array_equal(d.xyz[:, :2], scene.xyz[d.source, :2])
        assert np.array_equal(d.boxes, scene.boxes)
        sigmas.append(s)
    assert np.ptp(sigmas) > 0.005  # drawn per scene


def test_tilt_changes_z_by_distance_times_slope(scene):
    p = _params(dr_tilt_deg=[0.5, 0.5])
    d = domain_randomise(scene, p, np.random.default_rng(1))
    az, c = d.draws["tilt_azimuth_rad"], d.draws["centre"]
    assert d.draws["tilt_rad"] == pytest.approx(math.radians(0.5))
    # 10 m from the centre along the tilt azimuth: 10 tan(0.5 deg) = 8.7 cm higher; across it: 0
    probe = np.array([c + 10.0 * np.array([math.cos(az), math.sin(az)]),
                      c + 10.0 * np.array([-math.sin(az), math.cos(az)])])
    f = dr_z_field(probe, d.draws)
    assert f[0] == pytest.approx(10.0 * math.tan(math.radians(0.5)), abs=1e-9) and abs(f[1]) < 1e-9
    # the points: z moves by tan(slope) x their distance along the azimuth; the height feature does not
    dist = (scene.xyz[d.source, :2] - c) @ np.array([math.cos(az), math.sin(az)])
    dz = d.xyz[:, 2].astype(np.float64) - scene.xyz[d.source, 2]
    assert np.allclose(dz, dist * math.tan(math.radians(0.5)), atol=2e-5)
    assert np.array_equal(d.height, scene.height[d.source])
    assert np.ptp(dz) > 0.05
    # the boxes move with the field at their centres
    box_dz = d.boxes[:, 2].astype(np.float64) - scene.boxes[:, 2]
    assert np.allclose(box_dz, dr_z_field(scene.boxes[:, :2].astype(np.float64), d.draws), atol=2e-5)


def test_smile_is_one_percent_of_depth_at_65_deg_and_heave_is_bounded():
    base = {"centre": np.zeros(2), "tilt_rad": 0.0, "tilt_azimuth_rad": 0.0, "track_rad": 0.3,
            "track_offset_m": 0.0, "smile_depth_m": 11.5, "heave_m": 0.0, "heave_wavelength_m": 10.0,
            "heave_phase_rad": 0.0}
    across = np.array([-math.sin(0.3), math.cos(0.3)])
    u65 = 11.5 * math.tan(math.radians(65))
    probe = np.array([0.0 * across, u65 * across, -u65 * across, 2 * u65 * across])
    f = dr_z_field(probe, {**base, "smile_k": 0.0073})
    assert f[0] == pytest.approx(0.0, abs=1e-12)
    assert f[1] == pytest.approx(0.01 * 11.5, rel=0.01) and f[2] == pytest.approx(f[1])  # 1 % of depth
    assert f[3] == pytest.approx(f[1])  # flat beyond the swath edge
    assert dr_z_field(probe, {**base, "smile_k": -0.0073})[1] == pytest.approx(-f[1])  # frown
    xy = np.random.default_rng(0).uniform(-20, 20, (2000, 2))
    h = dr_z_field(xy, {**base, "smile_k": 0.0, "heave_m": 0.04})
    assert np.abs(h).max() <= 0.04 + 1e-12 and np.abs(h).max() > 0.035


def test_outliers_are_background_spikes_at_their_height(scene):
    p = _params(dr_outlier_frac=[0.05, 0.05], dr_outlier_height_m=[0.5, 1.5], n_points=1024)
    ground = _ground_model(scene, 2.0)[0]
    n = 0
    for seed in range(4):
        d = domain_randomise(scene, p, np.random.default_rng(seed))
        spike = d.source == -2
        n += spike.sum()
        assert (d.label[spike] == -1).all()
        assert ((d.height[spike] >= 0.5 - 1e-5) & (d.height[spike] <= 1.5 + 1e-5)).all()
        gz = ground(d.xyz[spike, :2].astype(np.float64))
        assert np.allclose(d.xyz[spike, 2] - gz, d.height[spike], atol=1e-4)  # height above the ground estimate
        for b in d.boxes:  # never inside an object's box (labels stay consistent with the boxes)
            assert not points_in_box(d.xyz[spike].astype(np.float64), b.astype(np.float64), margin_m=0.1).any()
        assert d.draws["n_outliers"] > 0
    # ~5 % of the kept points are added (minus those that fell on boxes), so ~5 % of the sample
    assert 0.01 < n / (4 * 1024) < 0.06


def test_leak_patches_raise_heights_and_let_seabed_through(scene):
    p = _params(dr_leak_patches=[3, 3], dr_leak_depth_m=[0.8, 0.8], n_points=1024)
    thr, cell = p["ground_height_m"], p["ground_cell_m"]
    d = domain_randomise(scene, p, np.random.default_rng(2))
    centres = d.draws["leak_centres"]
    leak = d.source == -1
    assert d.draws["n_leak"] > 0 and leak.any()
    assert (d.label[leak] == -1).all() and (d.height[leak] > thr).all()
    near = np.min(np.max(np.abs(d.xyz[leak, None, :2] - centres[None]), axis=2), axis=1)
    assert (near <= cell + 1e-4).all()  # only inside a dip (a one-cell hat of the ground grid)
    # scene points: the height rises by the dip (hat: 0.8 at a centre, 0 one cell away), z stays
    m = _real(d)
    dh = d.height[m].astype(np.float64) - scene.height[d.source[m]]
    xy = scene.xyz[d.source[m], :2].astype(np.float64)
    hat = np.zeros(len(xy))
    for c in centres:
        a = np.clip(1 - np.abs(xy - c) / cell, 0, None)
        hat = np.maximum(hat, 0.8 * a[:, 0] * a[:, 1])
    assert np.allclose(dh, hat, atol=2e-5)  # (patches in distinct cells: the dips do not add up)
    assert np.array_equal(d.xyz[m], scene.xyz[d.source[m]])


def test_dropout_blobs_are_empty(scene):
    p0 = _params(n_points=512)
    p = _params(dr_dropout_blobs=[3, 3], dr_dropout_radius_m=[1.0, 1.2], n_points=512)
    for seed in range(4):
        d = domain_randomise(scene, p, np.random.default_rng(seed))
        blobs = d.draws["blobs"]
        assert len(blobs) == 3
        inside_total = 0
        for cx, cy, a, b, t in blobs:
            def inside(xy):
                dx, dy = xy[:, 0] - cx, xy[:, 1] - cy
                u = (math.cos(t) * dx + math.sin(t) * dy) / a
                v = (-math.sin(t) * dx + math.cos(t) * dy) / b
                return u * u + v * v <= 1.0

            assert 1.0 <= a <= 1.2 and a / 3.0 - 1e-9 <= b <= a
            assert not inside(d.xyz[:, :2].astype(np.float64)).any()
            inside_total += inside(scene.xyz[:, :2].astype(np.float64)).sum()
        assert inside_total > 0  # the blobs did cover scene points (they are centred on points)
        d0 = domain_randomise(scene, p0, np.random.default_rng(seed))
        assert len(d0.draws["blobs"]) == 0


def test_density_field_changes_the_sampling_density(scene):
    """With contrast C the sampling weight spans [C^-1/2, C^1/2]; points in the densest quarter of the
    field are picked ~C^(1/2)..C times as often as those in the sparsest (measured over many draws)."""
    def ratio(contrast):
        p = _params(dr_density_contrast=[contrast, contrast], n_points=256)
        out = []
        for seed in range(60):
            d = domain_randomise(scene, p, np.random.default_rng(seed))
            w = dr_density_weight(scene.xyz[:, :2].astype(np.float64), d.draws)
            assert w.max() / w.min() == pytest.approx(contrast, rel=1e-6)
            q = np.quantile(w, [0.25, 0.75])
            picked = np.zeros(len(scene.xyz), bool)
            picked[d.source] = True
            out.append(picked[w >= q[1]].mean() / max(picked[w <= q[0]].mean(), 1e-9))
        return float(np.mean(out))

    ratio3, ratio1 = ratio(3.0), ratio(1.0)
    assert 1.5 < ratio3 < 3.5, ratio3
    assert 0.85 < ratio1 < 1.15, ratio1


def test_weighted_sample_without_replacement_and_padding():
    rng = np.random.default_rng(0)
    w = np.r_[np.zeros(10), np.ones(90)]
    idx = weighted_sample(w, 50, rng)
    assert len(np.unique(idx)) == 50 and idx.min() >= 10
    idx = weighted_sample(w, 120, rng)  # fewer positive weights than asked: every one once, then repeats
    assert len(idx) == 120 and set(np.unique(idx)) == set(range(10, 100))


def test_roughness_moves_object_points_only(scene):
    p = _params(dr_roughness_m=[0.03, 0.03], n_points=1024)
    d = domain_randomise(scene, p, np.random.default_rng(4))
    obj = d.label >= 0
    diff = d.xyz.astype(np.float64) - scene.xyz[d.source]
    assert np.array_equal(diff[~obj], np.zeros_like(diff[~obj]))
    assert np.allclose(diff[obj].std(axis=0), 0.03, rtol=0.1)
    dh = d.height.astype(np.float64) - scene.height[d.source]
    assert np.allclose(dh, diff[:, 2], atol=2e-5)


def test_line_offsets_in_strips_with_mixed_overlaps(scene):
    p = _params(dr_line_offset_m=[0.05, 0.05], dr_line_spacing_m=[6.0, 6.0], dr_line_overlap=0.5, n_points=1024)
    d = domain_randomise(scene, p, np.random.default_rng(5))
    S, dr = 6.0, d.draws
    offs, i0 = dr["line_offsets_m"], dr["line_first"]
    assert dr["line_sigma_m"] == 0.05 and len(offs) >= 3
    xy = scene.xyz[d.source, :2].astype(np.float64)
    tr_ = dr["track_rad"]
    c0, c1 = dr["centre"]
    v = -(xy[:, 0] - c0) * math.sin(tr_) + (xy[:, 1] - c1) * math.cos(tr_) + dr["line_shift_m"]
    dz = d.xyz[:, 2].astype(np.float64) - scene.xyz[d.source, 2]
    own = offs[np.floor(v / S).astype(int) - i0]
    frac = v / S - np.floor(v / S)
    core = (frac > 0.25 + 1e-6) & (frac < 0.75 - 1e-6)  # outside the overlap bands: the strip's own line
    assert core.any() and np.allclose(dz[core], own[core], atol=2e-5)
    assert np.allclose(d.height[core], scene.height[d.source[core]], atol=2e-5)  # the ground follows it
    band = ~core
    lo_l = offs[np.floor((v - 1.5) / S).astype(int) - i0]
    hi_l = offs[np.floor((v + 1.5) / S).astype(int) - i0]
    took = np.isclose(dz[band], lo_l[band], atol=2e-5) | np.isclose(dz[band], hi_l[band], atol=2e-5)
    assert took.all()  # in a band a point comes from one of the two lines
    mixed = ~np.isclose(dz[band], own[band], atol=2e-5)
    assert mixed.any()  # and some come from the neighbour
    dh = d.height[band].astype(np.float64) - scene.height[d.source[band]]
    assert np.allclose(dh, dz[band] - np.minimum(lo_l[band], hi_l[band]), atol=2e-5)
    bxy = scene.boxes[:, :2].astype(np.float64)
    vb = -(bxy[:, 0] - c0) * math.sin(tr_) + (bxy[:, 1] - c1) * math.cos(tr_) + dr["line_shift_m"]
    assert np.allclose(d.boxes[:, 2] - scene.boxes[:, 2], offs[np.floor(vb / S).astype(int) - i0], atol=2e-5)


def test_burial_sinks_objects_and_their_boxes(scene):
    p = _params(dr_burial_prob=1.0, dr_burial_m=[0.3, 0.3], n_points=1024)
    d = domain_randomise(scene, p, np.random.default_rng(6))
    assert np.allclose(d.draws["burial_m"], 0.3)  # all four rest on the seabed
    assert np.allclose(d.boxes[:, 2], scene.boxes[:, 2] - 0.3, atol=1e-6)
    assert np.allclose(d.axis[:, 2], scene.axis[:, 2] - 0.3, atol=1e-6)
    obj = d.label >= 0
    assert np.allclose(d.xyz[obj, 2] - scene.xyz[d.source[obj], 2], -0.3, atol=2e-5)
    assert (d.height[obj] > p["ground_height_m"]).all()  # the buried part is gone
    buried = (scene.label >= 0) & (scene.height <= p["ground_height_m"] + 0.3)
    assert buried.any() and not np.isin(np.flatnonzero(buried), d.source).any()
    for k, oid in enumerate(scene.obj_id):  # the points stay in their (lowered) boxes
        m = d.label == oid
        assert points_in_box(d.xyz[m].astype(np.float64), d.boxes[k].astype(np.float64), margin_m=0.05).mean() > 0.97


# ---------------------------------------------------------------------------------------------------
# everything on: labels, determinism, training
# ---------------------------------------------------------------------------------------------------

def test_all_effects_keep_labels_and_boxes_consistent(scene):
    p = resolve_params({**TINY, "dr_enabled": True, "dr_outlier_frac": [0.02, 0.02], "dr_leak_patches": [2, 4]})
    for seed in range(5):
        d = domain_randomise(scene, p, np.random.default_rng(seed))
        assert d.xyz.shape == (p["n_points"], 3) and d.xyz.dtype == np.float32
        assert d.height.shape == d.label.shape == d.source.shape == (p["n_points"],)
        assert np.isfinite(d.xyz).all() and np.isfinite(d.height).all() and np.isfinite(d.boxes).all()
        gen = d.source < 0
        assert (d.label[gen] == -1).all()
        assert np.array_equal(d.label[~gen], scene.label[d.source[~gen]])
        for k, oid in enumerate(scene.obj_id):
            m = d.label == oid
            if m.sum() >= 5:
                inside = points_in_box(d.xyz[m].astype(np.float64), d.boxes[k].astype(np.float64), margin_m=0.1)
                assert inside.mean() > 0.95
            assert not points_in_box(d.xyz[gen].astype(np.float64), d.boxes[k].astype(np.float64)).any()
        assert np.allclose(d.boxes[:, 3:], scene.boxes[:, 3:]) and np.allclose(d.boxes[:, :2], scene.boxes[:, :2])


def test_deterministic_for_a_fixed_seed_and_streams_independent(tmp_path, scene):
    p = resolve_params({**TINY, "dr_enabled": True})
    a = domain_randomise(scene, p, np.random.default_rng(11))
    b = domain_randomise(scene, p, np.random.default_rng(11))
    c = domain_randomise(scene, p, np.random.default_rng(12))
    for f in ("xyz", "height", "label", "boxes", "axis", "source"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert not np.array_equal(a.xyz, c.xyz)
    # changing one effect's range leaves the other effects' draws unchanged (one stream per effect)
    q = resolve_params({**TINY, "dr_enabled": True, "dr_outlier_frac": [0.0, 0.0]})
    e = domain_randomise(scene, q, np.random.default_rng(11))
    for k in ("noise_sigma_m", "tilt_rad", "smile_k", "line_sigma_m", "roughness_sigma_m", "density_contrast"):
        assert e.draws[k] == a.draws[k], k
    # batches: the same seeds give the same batch, and the scene itself is not modified
    before = scene.xyz.copy()
    b1 = tr._make_batch([scene, scene], p, np.random.default_rng(0), "cpu", True, np.random.default_rng(1))
    b2 = tr._make_batch([scene, scene], p, np.random.default_rng(0), "cpu", True, np.random.default_rng(1))
    assert all(torch.equal(b1[k], b2[k]) for k in b1)
    assert not torch.equal(b1["xyz"][0], b1["xyz"][1])  # each scene of a batch gets its own draws
    assert np.array_equal(scene.xyz, before)


def test_tiny_training_with_domain_randomisation(tmp_path):
    paths = [make_scene(tmp_path, f"d{i}", 20 + i, c) for i, c in enumerate((FOUR[:2], FOUR[2:]))]
    params = {**TINY, "epochs": 2, "batch_size": 2, "dr_enabled": True}
    s1 = train(paths, [], params, tmp_path / "a", resume=False)
    assert s1["steps"] == 2 and math.isfinite(s1["final_loss"]["loss"])
    s2 = train(paths, [], params, tmp_path / "b", resume=False)
    w1 = torch.load(tmp_path / "a" / "model.pt", weights_only=False)
    w2 = torch.load(tmp_path / "b" / "model.pt", weights_only=False)
    assert all(torch.equal(w1["state_dict"][k], w2["state_dict"][k]) for k in w1["state_dict"])  # deterministic
    assert s1["final_loss"]["loss"] == s2["final_loss"]["loss"]
    assert w1["settings"]["dr_enabled"] is True
    s0 = train(paths, [], {**params, "dr_enabled": False}, tmp_path / "c", resume=False)
    assert s0["final_loss"]["loss"] != s1["final_loss"]["loss"]  # it did change the training


def test_dr_parameters_are_validated():
    with pytest.raises(ValueError, match="dr_range_noise_m"):
        resolve_params({"dr_range_noise_m": [0.05, 0.01]})
    with pytest.raises(ValueError, match="dr_leak_patches"):
        resolve_params({"dr_leak_patches": [0.5, 2]})
    with pytest.raises(ValueError, match="dr_density_contrast"):
        resolve_params({"dr_density_contrast": [0.5, 2.0]})
    with pytest.raises(ValueError, match="dr_enabled"):
        resolve_params({"dr_enabled": "yes"})
    with pytest.raises(ValueError, match="dr_line_overlap"):
        resolve_params({"dr_line_overlap": 1.5})
