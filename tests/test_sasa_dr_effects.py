"""SASA's domain randomisation reuses the sensor effects' point-stage models (sonardet.sim.effects):
each reused model is on the DR path, and each does what its ``dr_*`` key's documentation says
(magnitudes measured on the randomised scenes).

Scenes are the tiny synthetic ones of test_sasa_model.py (see test_sasa_domain_randomisation.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_sasa_domain_randomisation import FOUR, OFF
from test_sasa_model import TINY, make_scene

from sonardet.detect.sasa import data as dr
from sonardet.detect.sasa import resolve_params
from sonardet.detect.sasa.data import (
    DR_STREAMS,
    _in_box_footprints,
    domain_randomise,
    dr_z_field,
    prepare_scene,
)
from sonardet.sim.effects import (
    attitude,
    burial,
    line_offsets,
    noise,
    outliers,
    refraction,
    roughness,
)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    p = resolve_params(TINY)
    return prepare_scene(make_scene(tmp_path_factory.mktemp("dr"), "dr", 7, FOUR), p)


def _params(**over):
    return resolve_params({**TINY, **OFF, **over})


def _stream(seed: int, name: str) -> np.random.Generator:
    """The child stream `name` that domain_randomise derives from default_rng(seed)."""
    base = int(np.random.default_rng(seed).integers(0, 2**63 - 1))
    return np.random.default_rng([base, DR_STREAMS.index(name)])


#: The sensor effects' functions domain randomisation uses, by the module that defines them.
REUSED = {
    "burial_depths": burial, "burial_dz": burial, "draw_spikes": outliers, "svp_bias_dz": refraction,
    "flat_seabed_cos": refraction, "roll_bias_dz": attitude, "heave_dz": attitude, "sinusoid": attitude,
    "line_offsets_m": line_offsets, "line_offset_dz": line_offsets, "range_noise_dz": noise,
    "roughness_point_offsets": roughness,
}


def test_every_reused_effect_model_is_on_the_dr_path(scene, monkeypatch):
    calls = dict.fromkeys(REUSED, 0)
    def spy(name, f):
        def counted(*a, **k):
            calls[name] += 1
            return f(*a, **k)
        return counted

    for name, module in REUSED.items():
        assert getattr(dr, name) is getattr(module, name)  # the effect's own function, not a copy
        monkeypatch.setattr(dr, name, spy(name, getattr(module, name)))
    p = resolve_params({**TINY, "dr_enabled": True, "dr_burial_prob": 1.0, "dr_outlier_frac": [0.02, 0.02],
                        "dr_tilt_deg": [0.3, 0.3], "dr_smile_coeff": [0.005, 0.005], "dr_heave_m": [0.03, 0.03],
                        "dr_line_offset_m": [0.03, 0.03], "dr_range_noise_m": [0.01, 0.01],
                        "dr_roughness_m": [0.01, 0.01]})
    domain_randomise(scene, p, np.random.default_rng(0))
    assert all(calls.values()), calls


def test_heave_is_the_uncompensated_heave_of_a_sinusoid_along_the_track(scene):
    p = _params(dr_heave_m=[0.05, 0.05])
    d = domain_randomise(scene, p, np.random.default_rng(3))
    dw, c = d.draws, d.draws["centre"]
    xy = scene.xyz[d.source, :2].astype(np.float64) - c
    along = xy[:, 0] * math.cos(dw["track_rad"]) + xy[:, 1] * math.sin(dw["track_rad"])
    expected = -0.05 * np.sin(2 * math.pi * along / dw["heave_wavelength_m"] + dw["heave_phase_rad"])
    dz = d.xyz[:, 2].astype(np.float64) - scene.xyz[d.source, 2]
    assert np.allclose(dz, expected, atol=2e-5) and 8.0 <= dw["heave_wavelength_m"] <= 20.0
    assert np.array_equal(d.height, scene.height[d.source])  # the ground estimate follows the smooth field
    # amplitude dr_heave_m: over one wavelength along the track the field spans +-0.05 m
    s = np.linspace(0, dw["heave_wavelength_m"], 2001)
    probe = c + s[:, None] * np.array([math.cos(dw["track_rad"]), math.sin(dw["track_rad"])])
    f = dr_z_field(probe, dw)
    assert f.max() == pytest.approx(0.05, abs=1e-5) and f.min() == pytest.approx(-0.05, abs=1e-5)


def test_smile_on_points_is_k_depth_sec_minus_one_across_the_track(scene):
    p = _params(dr_smile_coeff=[0.0073, 0.0073])
    d = domain_randomise(scene, p, np.random.default_rng(4))
    dw, c = d.draws, d.draws["centre"]
    xy = scene.xyz[d.source, :2].astype(np.float64) - c
    across = -xy[:, 0] * math.sin(dw["track_rad"]) + xy[:, 1] * math.cos(dw["track_rad"]) - dw["track_offset_m"]
    a = np.arctan(np.abs(across) / 11.5)  # the beam angle of a flat seabed 11.5 m below the virtual track
    expected = 0.0073 * 11.5 * (1 / np.cos(a) - 1)
    dz = d.xyz[:, 2].astype(np.float64) - scene.xyz[d.source, 2]
    assert np.allclose(dz, expected, atol=2e-5) and dz.min() >= -1e-5


def test_spikes_are_the_outlier_share_of_candidates_at_heights_in_range(scene):
    frac, lo, hi = 0.05, 0.5, 1.5
    p = _params(dr_outlier_frac=[frac, frac], dr_outlier_height_m=[lo, hi], n_points=len(scene.xyz))
    # share of the footprint outside the grown boxes, where spikes may fall
    gg = scene.meta["ground_grid"]
    q = np.random.default_rng(0).uniform(gg["lo"], gg["hi"], (200000, 2))
    free = 1.0 - _in_box_footprints(q, scene.boxes.astype(np.float64), dr.DR_BOX_MARGIN_M).mean()
    counts, heights = [], []
    for seed in range(40):
        d = domain_randomise(scene, p, np.random.default_rng(seed))
        counts.append(d.draws["n_outliers"])
        heights.append(d.height[d.source == -2].astype(np.float64))
    expected = frac * len(scene.xyz) * free
    assert abs(np.mean(counts) / expected - 1) < 0.08, (np.mean(counts), expected)
    h = np.concatenate(heights)
    assert h.min() >= lo - 1e-5 and h.max() <= hi + 1e-5
    assert abs(h.mean() - 0.5 * (lo + hi)) < 0.03 and abs(h.std() - (hi - lo) / math.sqrt(12)) < 0.02  # uniform


def test_range_noise_is_the_sensors_float32_noise_with_the_drawn_sigma(scene):
    p = _params(dr_range_noise_m=[0.0, 0.03], n_points=1024)
    for seed in range(3):
        d = domain_randomise(scene, p, np.random.default_rng(seed))
        r = _stream(seed, "noise")
        sigma = float(r.uniform(0.0, 0.03))
        assert sigma == d.draws["noise_sigma_m"]
        err = noise.range_noise((1024,), sigma, r)  # what the scan adds to its ranges
        assert err.dtype == np.float32
        dz = d.xyz[:, 2].astype(np.float64) - scene.xyz[d.source, 2]
        assert np.allclose(dz, -err.astype(np.float64), atol=2e-5)  # a vertical beam: z moves by -error
        assert abs(dz.std() - sigma) < 0.1 * sigma


def test_burial_draws_each_resting_objects_depth_in_range(scene):
    p = _params(dr_burial_prob=1.0, dr_burial_m=[0.1, 0.3], n_points=1024)
    depths = np.concatenate([domain_randomise(scene, p, np.random.default_rng(s)).draws["burial_m"]
                             for s in range(10)])
    assert ((depths >= 0.1) & (depths <= 0.3)).all() and len(np.unique(depths)) == len(depths)
    assert abs(depths.mean() - 0.2) < 0.03


def test_line_offsets_have_the_drawn_sigma(scene):
    p = _params(dr_line_offset_m=[0.04, 0.04], dr_line_spacing_m=[1.0, 1.0], n_points=512)
    offs = np.concatenate([domain_randomise(scene, p, np.random.default_rng(s)).draws["line_offsets_m"]
                           for s in range(40)])
    assert len(offs) > 400 and abs(offs.std() - 0.04) < 0.1 * 0.04 and abs(offs.mean()) < 0.01


def _in_box_footprints_numpy(xy, boxes, margin_m):
    """The NumPy form `_in_box_footprints` compiles (one box at a time)."""
    inside = np.zeros(len(xy), bool)
    for b in boxes:
        hl, hw = 0.5 * b[3] + margin_m, 0.5 * b[4] + margin_m
        r = math.hypot(hl, hw)
        near = np.flatnonzero((np.abs(xy[:, 0] - b[0]) <= r) & (np.abs(xy[:, 1] - b[1]) <= r))
        d = xy[near] - b[:2]
        c, s = math.cos(b[6]), math.sin(b[6])
        inside[near[(np.abs(c * d[:, 0] + s * d[:, 1]) <= hl) & (np.abs(-s * d[:, 0] + c * d[:, 1]) <= hw)]] = True
    return inside


def test_box_footprints_compiled_equal_the_numpy_form(scene):
    rng = np.random.default_rng(3)
    boxes = scene.boxes.astype(np.float64)
    xy = np.r_[rng.uniform(-12, 12, (4000, 2)), boxes[:, :2] + rng.normal(0, 0.8, (len(boxes), 2)),
               [[np.nan, 0.0], [0.0, np.inf]]]
    # points exactly on a footprint's edge (yaw 0): the <= tests keep them
    edge = np.array([[0.0, 0.0, 0.0, 2.0, 1.0, 1.0, 0.0]])
    on_edge = np.array([[1.0 + 0.2, 0.0], [0.0, 0.5 + 0.2], [1.2000001, 0.0]])
    for pts, bx in ((xy, boxes), (on_edge, edge), (xy, boxes[:0])):
        got = _in_box_footprints(pts, bx, dr.DR_BOX_MARGIN_M if bx is boxes else 0.2)
        np.testing.assert_array_equal(got, _in_box_footprints_numpy(pts, bx, dr.DR_BOX_MARGIN_M if bx is boxes
                                                                   else 0.2))
    assert _in_box_footprints(on_edge, edge, 0.2).tolist() == [True, True, False]


def test_leak_dips_only_near_dip_cells_equal_the_full_interpolation():
    """`_hat_dip` interpolates only points next to a dip cell; every point gets the value of the full
    bilinear interpolation, bit for bit (zeros elsewhere), also beyond the grid's edges."""
    rng = np.random.default_rng(5)
    lo, cell, shape = np.array([-10.0, -7.5]), 0.5, (40, 30)
    for cells in (np.array([[0, 0], [39, 29], [12, 7], [12, 8], [0, 29]]), rng.integers(0, 30, (12, 2)),
                  np.zeros((0, 2), np.int64)):
        grid = np.zeros(shape)
        if len(cells):
            np.maximum.at(grid, (cells[:, 0], cells[:, 1]), rng.uniform(0.1, 0.4, len(cells)))

        def dip(q):
            return dr.ground_at(lo, grid, cell, q)

        xy = np.r_[rng.uniform(lo - 1.0, lo + np.array(shape) * cell + 1.0, (20000, 2)),
                   lo + (cells[:, :2] + 0.5) * cell, lo + (cells[:, :2] + 1.5) * cell]
        got = dr._hat_dip(xy, dip, lo, cell, shape, cells)
        want = dip(xy)
        assert got.tobytes() == want.tobytes()
        assert (got > 0).sum() == (want > 0).sum() and ((got > 0).sum() > 0) == (len(cells) > 0)
