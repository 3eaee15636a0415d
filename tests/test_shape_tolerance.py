"""The training-free detector on objects that differ from their models (gross geometry): a tetrapod
with thinner or thicker legs at the same height, a fouling shell on every class.

The objects come from `sonardet.objects.perturb` (the mismatch test set's perturbations) and are
scanned with the project's own sonar model over a flat seabed, one object per scene. The checks use
the detector's defaults (shape tolerance and height check on: `shape_tolerance_frac`,
`overhang_max_frac`, `overhang_core_frac`), and unit checks of the two mechanisms.
"""

from __future__ import annotations

import numpy as np
import pytest

# The fixtures and scan helpers of the model-based tests (default objects, reduced template views).
from test_model_based import accepted, cfg, objects, place, sensor, survey, templates  # noqa: F401

from sonardet.detect.model_based import detect
from sonardet.detect.model_based.scoring import (
    Hypothesis,
    height_consistency,
    shape_tolerance_m,
    tolerant_distance,
)
from sonardet.objects import canonical_box
from sonardet.objects.perturb import perturbed_object

pytestmark = pytest.mark.slow


_TETRAPOD = dict(broken_leg=None, broken_frac=0.0, rounded=False, fouling_m=0.0, fouling_seed=1)
CASES = [
    ("tetrapod_b", dict(_TETRAPOD, leg_scale=0.65)),  # thin legs: as wide as a tetrapod_s, 0.66 m taller
    ("tetrapod_b", dict(_TETRAPOD, leg_scale=1.35)),
    ("tetrapod_s", dict(_TETRAPOD, leg_scale=1.35)),  # thick legs: as wide as a tetrapod_b, 0.66 m lower
    ("tetrapod_s", dict(_TETRAPOD, leg_scale=0.65)),
    ("tetrapod_b", dict(_TETRAPOD, leg_scale=1.0, fouling_m=0.05, fouling_seed=4)),
    ("reef_cone", dict(top_scale=1.0, n_holes=30, hole_seed=3, fouling_m=0.05, fouling_seed=2)),
    ("reef_ring", dict(n_ribs=6, wall_scale=1.0, fouling_m=0.05, fouling_seed=2)),
]


@pytest.mark.parametrize("cls,record", CASES, ids=[f"{c}-{'-'.join(f'{k}{v}' for k, v in r.items() if k in ('leg_scale', 'fouling_m'))}"
                                                   for c, r in CASES])
def test_an_object_unlike_its_model_keeps_its_class(cfg, objects, templates, sensor, cls, record):  # noqa: F811
    obj = perturbed_object(cls, record, cfg["objects"], objects[cls])
    t, q = place(obj, 7.0, 6.5, 0.7)
    xyz = survey([(obj, t, q)], sensor)
    truth = canonical_box(obj.mesh.vertices, t, q, obj.symmetry_order)
    dets = accepted(detect(xyz, templates, objects, None, "ours")[0])
    assert [d["cls"] for d in dets] == [cls], [(d["cls"], round(d["score"], 3)) for d in dets]
    assert np.linalg.norm(np.asarray(dets[0]["box"][:3]) - truth[:3]) < 0.3


def test_the_tolerance_scales_with_the_class(objects, templates):  # noqa: F811
    from sonardet.detect.model_based import DEFAULTS
    from sonardet.detect.model_based.models import build_class_model

    ring = build_class_model(templates["reef_ring"], objects["reef_ring"], 0.05)
    tb = build_class_model(templates["tetrapod_b"], objects["tetrapod_b"], 0.05)
    off = dict(DEFAULTS, shape_tolerance_frac=0.0)
    assert shape_tolerance_m(tb, off) == 0.0
    # Half thicknesses measured on the meshes: a ring wall (9 and 6 cm) against a tetrapod leg's radius.
    assert 0.02 < ring.half_thickness_m < 0.06 and 0.3 < tb.half_thickness_m < 0.6
    p = dict(DEFAULTS, shape_tolerance_frac=0.35)
    assert shape_tolerance_m(tb, p) == pytest.approx(0.35 * tb.half_thickness_m)
    assert shape_tolerance_m(ring, p) < 0.25 * shape_tolerance_m(tb, p)
    # A shell of points 5 cm outside the leg surface is within the tolerance; without it, 5 cm off.
    pts = tb.surface[::50] + 0.05 * tb.surface_normals[::50]
    assert np.median(tolerant_distance(tb, pts, off)) == pytest.approx(0.05, abs=0.01)
    assert np.all(tolerant_distance(tb, pts, p) < 0.02)
    # Signed distances: outside positive, inside negative.
    assert np.median(tb.signed_distance(pts)) > 0 > np.median(tb.signed_distance(tb.surface[::50] - 0.05 * tb.surface_normals[::50]))


def test_height_consistency_falls_with_the_height_of_unexplained_points():
    h = Hypothesis("tetrapod_s", np.eye(3), np.zeros(3), np.zeros(7), over=np.arange(10), over_range_m=1.0)
    params = {"overhang_min_points_n": 5}
    active = np.ones(10, bool)
    h.over_dz = np.full(10, 0.25)
    assert height_consistency(h, active, params) == pytest.approx(0.75)
    h.over_dz = np.r_[np.full(4, 2.0), np.zeros(6)]  # four spikes: fewer than n, ignored
    assert height_consistency(h, active, params) == pytest.approx(1.0)
    h.over_dz = np.full(10, 3.0)
    assert height_consistency(h, active, params) == 0.0
    active[:] = False  # explained by another object: no penalty
    assert height_consistency(h, active, params) == 1.0
    h.over_range_m = 0.0  # the check off
    assert height_consistency(h, np.ones(10, bool), params) == 1.0


def test_points_of_an_object_above_do_not_count_as_overhang():
    from sonardet.detect.model_based.scoring import support_overhangs

    # Candidate points 0-9 above a lower box (top at z = 1.0); points 0-5 are inliers of a hypothesis
    # centred above that top (the ring on top of a stack), so only 6-9 count.
    low = Hypothesis("reef_ring", np.eye(3), np.zeros(3), np.array([0, 0, 0.5, 2.7, 2.7, 1.0, 0]),
                     over=np.arange(10), over_dz=np.full(10, 0.4), over_range_m=0.5,
                     cand=np.arange(12), inl=np.ones(12, bool))
    up = Hypothesis("reef_ring", np.eye(3), np.zeros(3), np.array([0, 0, 1.3, 2.7, 2.7, 0.75, 0]),
                    cand=np.arange(6), inl=np.ones(6, bool))
    # A taller object's hypothesis centred below the small box's top supports nothing.
    tall = Hypothesis("tetrapod_b", np.eye(3), np.zeros(3), np.array([0, 0, 0.9, 2.0, 2.0, 2.0, 0]),
                      cand=np.arange(6, 10), inl=np.ones(4, bool))
    support_overhangs([low, up, tall], 12)
    assert low.over_free.tolist() == [False] * 6 + [True] * 4
    params = {"overhang_min_points_n": 5}
    assert height_consistency(low, np.ones(12, bool), params) == 1.0  # 4 free points < n
    params = {"overhang_min_points_n": 4}
    assert height_consistency(low, np.ones(12, bool), params) == pytest.approx(0.2)


def _member(cand, inl_idx, f_t=0.9, rmse_m=0.02, cls="tetrapod_s"):
    cand = np.asarray(cand)
    return Hypothesis(cls, np.eye(3), np.zeros(3), np.zeros(7), f_t=f_t, rmse_m=rmse_m,
                      cand=cand, inl=np.isin(cand, inl_idx), over_range_m=0.0)


def test_touching_pile_members_do_not_count_against_each_other():
    from sonardet.detect.model_based.scoring import rescore, support_neighbours

    # Points 0-9 are member a's surface, 10-19 member b's; each box holds 5 of the other's points.
    params = {"neighbour_support_overlap_max_frac": 0.2, "neighbour_support_f_t_min": 0.6}
    rmse_max = {"tetrapod_s": 0.05, "tetrapod_b": 0.05}
    active = np.ones(40, bool)
    a = _member(np.r_[0:10, 10:15], np.arange(0, 10))
    b = _member(np.r_[10:20, 5:10], np.arange(10, 20))
    assert rescore(a, active, 0.05, params | {"overhang_min_points_n": 5}) == pytest.approx(0.9 * 10 / 15 * 0.84)
    support_neighbours([a, b], [a, b], 40, rmse_max, params)
    assert a.cand_free.tolist() == [True] * 10 + [False] * 5
    rescore(a, active, 0.05, params | {"overhang_min_points_n": 5})
    rescore(b, active, 0.05, params | {"overhang_min_points_n": 5})
    assert a.f_s == 1.0 and b.f_s == 1.0
    # Points nobody explains keep counting: c's box also holds 20-24, inliers of no hypothesis.
    c = _member(np.r_[0:10, 20:25], np.arange(0, 10))
    support_neighbours([c], [b], 40, rmse_max, params)
    rescore(c, active, 0.05, params | {"overhang_min_points_n": 5})
    assert c.f_s == pytest.approx(10 / 15)


@pytest.mark.parametrize("case", ["same object", "poor coverage", "poor fit", "off"])
def test_fits_of_one_object_and_poor_fits_support_nothing(case):
    from sonardet.detect.model_based.scoring import support_neighbours

    params = {"neighbour_support_overlap_max_frac": 0.2, "neighbour_support_f_t_min": 0.6}
    a = _member(np.r_[0:10, 10:15], np.arange(0, 10))
    if case == "same object":  # a small class on part of a big object: most inliers shared
        other = _member(np.r_[0:15], np.r_[3:15], cls="tetrapod_b")
    elif case == "poor coverage":
        other = _member(np.r_[10:20], np.arange(10, 20), f_t=0.3)
    elif case == "poor fit":
        other = _member(np.r_[10:20], np.arange(10, 20), rmse_m=0.2)
    else:
        other = _member(np.r_[10:20], np.arange(10, 20))
        params["neighbour_support_overlap_max_frac"] = 0.0
    support_neighbours([a], [a, other], 40, {"tetrapod_s": 0.05, "tetrapod_b": 0.05}, params)
    assert a.cand_free is None or a.cand_free.all()


def test_template_views_move_along_the_normals_of_their_nearest_surface_samples(objects, templates):  # noqa: F811
    """The prepared views (scoring.CoverageViews) offset exactly as a per-hypothesis tree query would."""
    from sonardet.detect.model_based.models import build_class_model
    from sonardet.detect.model_based.scoring import (
        CoverageViews,
        _offset_along_normals,
        view_points,
    )

    tb = build_class_model(templates["tetrapod_b"], objects["tetrapod_b"], 0.05)
    views = view_points(tb.views, 0.1)
    tv = CoverageViews.of(tb, views)
    assert len(tv.bounds) == len(views) + 1 and tv.bounds[-1] == len(tv.points)
    for off in (-0.12, 0.0, 0.07):
        assert np.array_equal(tv.points + off * tv.normals if off else tv.points,
                              _offset_along_normals(tb, np.concatenate(views), off))


def test_within_is_the_distance_test(objects, templates):  # noqa: F811
    """`ClassModel.within` (bounded nearest-sample search) answers distance(p) < d exactly, for
    points on, near and far from the surface, at bounds below and above 1.5 sample spacings."""
    from sonardet.detect.model_based.models import build_class_model

    tb = build_class_model(templates["tetrapod_b"], objects["tetrapod_b"], 0.05)
    rng = np.random.default_rng(5)
    near = tb.surface[::7] + rng.normal(0.0, 0.06, (len(tb.surface[::7]), 3))
    far = rng.uniform(-3.0, 3.0, (4000, 3))
    pts = np.concatenate([near, far])
    for d in (0.01, 0.05, 0.075, 0.1, 0.3):
        got, want = tb.within(pts, d), tb.distance(pts) < d
        assert np.array_equal(got, want), d
        assert 0 < want.sum() < len(pts)  # both answers occur
    assert tb.within(np.zeros((0, 3)), 0.1).shape == (0,)


def test_bounded_signed_distance_equals_the_full_one_below_the_bound(objects, templates):  # noqa: F811
    """`signed_distance(p, bound_m)`: the same signed values as the unbounded search wherever |d| is
    below the bound, +inf elsewhere, at bounds below and above 1.5 sample spacings."""
    from sonardet.detect.model_based.models import build_class_model

    tb = build_class_model(templates["tetrapod_b"], objects["tetrapod_b"], 0.05)
    rng = np.random.default_rng(6)
    near = tb.surface[::7] + rng.normal(0.0, 0.06, (len(tb.surface[::7]), 3))
    pts = np.concatenate([near, rng.uniform(-3.0, 3.0, (4000, 3))])
    full = tb.signed_distance(pts)
    for bound in (0.02, 0.06, 0.1, 0.25):
        got = tb.signed_distance(pts, bound_m=bound)
        below = np.abs(full) < bound
        assert 0 < below.sum() < len(pts)
        assert np.array_equal(got[below], full[below]), bound
        assert np.all(np.isposinf(got[~below])), bound
    assert np.array_equal(tb.signed_distance(pts, bound_m=np.inf), full)


def test_virtual_views_cast_only_the_rays_that_can_hit(objects, templates):  # noqa: F811
    """`virtual_views` leaves out the rays outside the mesh's extent on each view plane: the hit points
    equal those of the full ray grid (a plain reference), for every class and several poses."""
    import open3d as o3d

    from sonardet.detect.model_based.models import build_class_model, rot_x, rot_z
    from sonardet.detect.model_based.params import DEFAULTS
    from sonardet.detect.model_based.scoring import view_directions, virtual_views

    def full_grid(model, R, t, cell_m, directions):
        v = model.vertices @ R.T + t
        c = 0.5 * (v.min(0) + v.max(0))
        r = 0.5 * float(np.linalg.norm(v.max(0) - v.min(0))) + cell_m
        g = np.arange(-r, r + 1e-9, cell_m)
        gu, gv = np.meshgrid(g, g)
        out = []
        for d in directions:
            u = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
            u /= np.linalg.norm(u)
            w = np.cross(d, u)
            o = c - 2.0 * r * d + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * w
            rays = np.empty((len(o), 6), dtype=np.float32)
            rays[:, :3] = (o - t) @ R
            rays[:, 3:] = d @ R
            dk = model.raycaster.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
            hit = np.isfinite(dk)
            out.append(o[hit] + dk[hit, None] * d)
        return out

    p = dict(DEFAULTS)
    dirs = view_directions(p["virtual_view_incidences_deg"], int(p["virtual_view_azimuths_n"]))
    for cls in ("reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"):
        m = build_class_model(templates[cls], objects[cls], 0.06)
        for R in (rot_z(0.3) @ rot_x(1.1), rot_x(2.0), rot_z(1.3)):
            t = np.array([2.0, -1.0, -11.0])
            got = virtual_views(m, R, t, p["coverage_voxel_m"], dirs)
            want = full_grid(m, R, t, p["coverage_voxel_m"], dirs)
            assert len(got) == len(want) == len(dirs)
            for a, b in zip(got, want):
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
            assert sum(len(a) for a in got) > 100


def test_virtual_coverage_of_all_views_at_once_equals_the_loop_over_views(objects, templates):  # noqa: F811
    """`_coverage_virtual` (the views' points tested together, counted per view) equals the share
    computed view by view (views below virtual_view_min_points_n left out), with a shape offset,
    occluders and a shadow map."""
    from sonardet.detect.model_based.models import build_class_model, rot_x, rot_z
    from sonardet.detect.model_based.near import NearGrid
    from sonardet.detect.model_based.params import DEFAULTS
    from sonardet.detect.model_based.scoring import (
        ShadowMap,
        _asked,
        _coverage_virtual,
        _excused,
        _offset_along_normals,
        view_directions,
        virtual_views,
    )

    tb = build_class_model(templates["tetrapod_s"], objects["tetrapod_s"], 0.05)
    p = dict(DEFAULTS)
    rng = np.random.default_rng(9)
    R, t = rot_z(0.7) @ rot_x(1.2), np.array([1.0, 2.0, -11.0])
    dirs = view_directions(p["virtual_view_incidences_deg"], int(p["virtual_view_azimuths_n"]))
    views = virtual_views(tb, R, t, p["coverage_voxel_m"], dirs)
    seen = np.concatenate(views)
    for k, (drop, offset) in enumerate(((0.3, 0.0), (0.6, 0.04), (0.9, -0.03))):
        scene = seen[rng.random(len(seen)) >= drop] + rng.normal(0, 0.01, (1, 3))
        near = NearGrid(scene, p["coverage_m"])
        shadow = ShadowMap(scene + [0.0, 0.0, 0.4], p["shadow_cell_m"], p["shadow_margin_m"]) if k == 1 else None
        occluders = [np.array([t[0] + 0.4, t[1], t[2] + 1.0, 1.0, 1.0, 2.0, 0.0])] if k == 2 else []
        want = 0.0
        for pv in views:
            if len(pv) < p["virtual_view_min_points_n"]:
                continue
            if offset:
                pv = _offset_along_normals(tb, (pv - t) @ R, offset) @ R.T + t
            hit = near.any_within(pv)
            asked = _asked(pv, occluders, p) & ~_excused(pv, hit, shadow)
            want = max(want, float((hit & asked).sum() / max(asked.sum(), p["coverage_asked_min_frac"] * len(pv), 1.0)))
        got = _coverage_virtual(tb, R, t, near, occluders, p, offset, shadow)
        assert got == want and 0.0 < got <= 1.0, (k, got, want)
    # No view with enough points: 0.
    assert _coverage_virtual(tb, R, t, near, [], dict(p, virtual_view_min_points_n=10**9)) == 0.0


def test_upright_coverage_per_view_counts_equal_the_loop_over_views(objects, templates):  # noqa: F811
    """`_coverage_upright` (per-view counts from cumulative sums) equals the share computed view by view,
    with occluders, a shadow map and empty views among them."""
    from scipy.spatial import cKDTree

    from sonardet.detect.model_based.models import build_class_model, rot_z
    from sonardet.detect.model_based.near import NearGrid
    from sonardet.detect.model_based.params import DEFAULTS
    from sonardet.detect.model_based.scoring import (
        CoverageViews,
        ShadowMap,
        _asked,
        _coverage_upright,
        _excused,
        view_points,
    )

    tb = build_class_model(templates["tetrapod_b"], objects["tetrapod_b"], 0.05)
    views = view_points(tb.views, 0.1)
    views = [views[0], np.zeros((0, 3)), *views[1:], np.zeros((0, 3))]  # empty views, inside and last
    tv = CoverageViews.of(tb, views)
    p = dict(DEFAULTS)
    rng = np.random.default_rng(2)
    R, t = rot_z(0.4), np.array([3.0, -2.0, -11.0])
    for k, drop in enumerate((0.0, 0.5, 0.95)):
        scene = views[2][rng.random(len(views[2])) >= drop] @ R.T + t + rng.normal(0, 0.02, (1, 3))
        ltree = cKDTree(scene)
        shadow = ShadowMap(scene + [0.0, 0.0, 0.5], p["shadow_cell_m"], p["shadow_margin_m"]) if k == 1 else None
        occluders = [np.array([t[0] + 0.5, t[1], t[2] + 1.0, 1.0, 1.0, 2.0, 0.0])] if k == 2 else []
        allv = tv.points @ R.T + t
        hit = np.isfinite(ltree.query(allv, k=1, distance_upper_bound=p["coverage_m"])[0])
        asked = _asked(allv, occluders, p) & ~_excused(allv, hit, shadow)
        want = max((hit[a:b] & asked[a:b]).sum() / max(asked[a:b].sum(), p["coverage_asked_min_frac"] * (b - a), 1.0)
                   for a, b in zip(tv.bounds[:-1], tv.bounds[1:]))
        got = _coverage_upright(tv, R, t, NearGrid(scene, p["coverage_m"]), occluders, p, 0.0, shadow)
        assert got == want and 0.0 < got <= 1.0, (k, got, want)
