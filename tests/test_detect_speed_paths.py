"""The faster paths of the `ours` detector give what the slower ones gave: the coverage test's column
grid against SciPy's k-d tree, the one-call virtual views against one cast per view, and the refit
gate (no refit of a hypothesis whose inliers the accepted object took)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

import sonardet.detect.model_based.ours as ours
from sonardet.config import validate_config
from sonardet.detect.model_based import DEFAULTS
from sonardet.detect.model_based.models import build_class_model
from sonardet.detect.model_based.near import NearGrid
from sonardet.detect.model_based.scoring import Hypothesis, view_directions, virtual_views
from sonardet.detect.model_based.tasks import task_stats
from sonardet.objects import build_object, object_info
from sonardet.sim.mbes import SensorConfig
from sonardet.sim.templates import scan_templates


def _kdtree_hits(pts, q, r):
    if len(pts) == 0:
        return np.zeros(len(q), dtype=bool)
    d, _ = cKDTree(pts).query(q, k=1, distance_upper_bound=r)
    return np.isfinite(d)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_near_grid_matches_the_kdtree(seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-1, -1, -0.5], [2, 1.5, 1.0], size=(2000, 3))
    pts[:200] = pts[0] + rng.normal(0, 0.01, (200, 3))  # a dense clump: long columns
    pts[200:400, 2] = np.round(pts[200:400, 2], 1)  # equal heights within a column
    q = rng.uniform([-1.5, -1.5, -1.0], [2.5, 2.0, 1.5], size=(20000, 3))  # some off the grid
    for r in (0.03, 0.08, 0.2):
        g = NearGrid(pts, r)
        for c in range(g.nx * g.ny):  # each column sorted by height, holding the points of that column
            assert np.all(np.diff(g.pts[g.start[c]:g.start[c + 1], 2]) >= 0)
        as_rows = lambda a: np.sort(np.ascontiguousarray(a).view("f8,f8,f8"), axis=0)  # noqa: E731
        np.testing.assert_array_equal(as_rows(g.pts), as_rows(pts))  # the same points, none lost
        got = g.any_within(q)
        want = _kdtree_hits(pts, q, r)
        assert want.any() and (~want).any()
        np.testing.assert_array_equal(got, want)


def test_near_grid_edge_cases():
    q = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.49]])
    g = NearGrid(np.zeros((1, 3)), 0.5)
    np.testing.assert_array_equal(g.any_within(q), [True, False, True])  # strictly closer, as the k-d tree
    assert not NearGrid(np.zeros((0, 3)), 0.1).any_within(q).any()
    assert NearGrid(np.zeros((1, 3)), 0.1).any_within(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError, match="radius"):
        NearGrid(np.zeros((1, 3)), 0.0)


@pytest.fixture(scope="module")
def model():
    cfg = validate_config({})
    obj = object_info(build_object("tetrapod_s", cfg["objects"]), cfg["objects"]["density_kg_m3"])
    tv = scan_templates("tetrapod_s", obj.mesh.vertices, obj.mesh.faces, obj.symmetry_order,
                        {"yaw_deg": [0], "directions": ["x"], "offsets_m": [0.0], "altitude_m": 11.5},
                        SensorConfig.from_dict(cfg["sensor"]), np.random.default_rng(0))
    return build_class_model(tv, obj, DEFAULTS["surface_spacing_m"])


def test_virtual_views_in_one_cast_equal_one_cast_per_view(model):
    """The views of a tilted pose, cast in one call, hit the same surface points as the casts of one
    view at a time (the rays of every view as `virtual_views` builds them)."""
    a, b = np.deg2rad(35.0), np.deg2rad(20.0)
    R = np.array([[np.cos(b), -np.sin(b), 0], [np.sin(b), np.cos(b), 0], [0, 0, 1]]) @ \
        np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    t = np.array([3.0, -2.0, -11.0])
    dirs = view_directions([0.0, 30.0, 50.0], 4)
    cell = 0.1
    got = virtual_views(model, R, t, cell, dirs)
    v = model.vertices @ R.T + t
    c = 0.5 * (v.min(0) + v.max(0))
    r = 0.5 * float(np.linalg.norm(v.max(0) - v.min(0))) + cell
    g = np.arange(-r, r + 1e-9, cell)
    gu, gv = np.meshgrid(g, g)
    assert len(got) == len(dirs)
    for d, pv in zip(dirs, got):
        u = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        o = c - 2.0 * r * d + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * w
        dist = model.cast_down((o - t) @ R, R.T @ d)
        hit = np.isfinite(dist)
        assert hit.sum() > 50
        np.testing.assert_allclose(pv, o[hit] + dist[hit, None] * d, atol=1e-6)


def test_refit_gate_spares_hypotheses_whose_inliers_were_taken(monkeypatch):
    """Of two pending hypotheses that lost 40 % of their candidates, the one that lost its inliers
    (another explanation of the object just accepted) is re-scored, the one that lost other points
    (a neighbour's leg) is refitted; with the gate at 1 both are refitted."""
    n = 100
    pts = np.c_[np.linspace(0, 1, n), np.zeros(n), np.full(n, 0.5)]

    class St:
        pass

    st = St()
    st.pts, st.active = pts, np.ones(n, dtype=bool)
    st.tree_xy = cKDTree(pts[:, :2])
    st.pool = None  # no worker threads
    cand = np.arange(50)
    inl = np.zeros(50, dtype=bool)
    inl[:20] = True  # inliers: points 0-19

    def hyp():
        return Hypothesis(cls="tetrapod_s", R=np.eye(3), t=np.array([0.2, 0.0, 0.0]), box=np.zeros(7),
                          f_t=0.9, rmse_m=0.01, cand=cand.copy(), inl=inl.copy())

    calls = []
    monkeypatch.setattr(ours, "_fit", lambda st_, k, R0, t0, crop, p, stats, occ=(), kind="refit": calls.append(1))

    class K:
        class model:
            radius_m = 1.0

    p = dict(DEFAULTS)
    for gate, want in ((DEFAULTS["refit_inliers_lost_max_frac"], 1), (1.0, 2)):
        calls.clear()
        took_inliers, took_others = np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        took_inliers[:20] = True  # all of the first hypothesis' inliers
        took_others[30:50] = True  # candidates, no inliers
        for gone in (took_inliers, took_others):
            h = hyp()
            ours._update_pending(st, {"tetrapod_s": K}, [h], [], gone, gone.copy(),
                                 dict(p, refit_inliers_lost_max_frac=gate), task_stats(),
                                 {"tetrapod_s": 0.05})
        assert len(calls) == want


def _shadow_tops_numpy(pts, cell):
    """The shadow map's raster as written with NumPy and SciPy (the reference of the compiled pass)."""
    from scipy import ndimage as ndi

    lo = pts[:, :2].min(0) - cell
    ij = np.floor((pts[:, :2] - lo) / cell).astype(np.int64)
    top = np.full(ij.max(0) + 2, -np.inf)
    np.maximum.at(top, (ij[:, 0], ij[:, 1]), pts[:, 2])
    return ndi.maximum_filter(top, size=3, mode="constant", cval=-np.inf)


@pytest.mark.parametrize("seed", [0, 1])
def test_shadow_map_raster_equals_numpy_and_scipy(seed):
    from sonardet.detect.model_based.scoring import ShadowMap

    rng = np.random.default_rng(seed)
    pts = rng.uniform([-3, 5, -12], [1, 7, -10], size=(3000, 3))
    pts[:50] = pts[0]  # repeated points: one cell, one height
    for cell in (0.1, 0.15, 0.4):
        np.testing.assert_array_equal(ShadowMap(pts, cell, 0.2).top, _shadow_tops_numpy(pts, cell))
    one = np.array([[2.0, -1.0, -11.0]])
    np.testing.assert_array_equal(ShadowMap(one, 0.15, 0.2).top, _shadow_tops_numpy(one, 0.15))


def test_seabed_cell_medians_equal_numpy_median():
    from sonardet.detect.model_based.ground import _cell_stat

    rng = np.random.default_rng(3)
    shape = (7, 9)
    ix, iy = rng.integers(0, shape[1], 5000), rng.integers(0, shape[0], 5000)
    keep = ~((ix == 4) & (iy == 2))  # one empty cell
    ix, iy = ix[keep], iy[keep]
    z = np.round(rng.normal(-11.0, 0.3, len(ix)), 2)  # ties
    got = _cell_stat(ix, iy, z, shape, "median")
    for i in range(shape[0]):
        for j in range(shape[1]):
            sel = (iy == i) & (ix == j)
            if sel.any():
                assert got[i, j] == np.median(z[sel])
            else:
                assert np.isnan(got[i, j])
    assert np.isnan(_cell_stat(ix[:0], iy[:0], z[:0], shape, "median")).all()


def test_tasks_run_in_order_and_merge_their_statistics():
    from sonardet.detect.model_based.tasks import run_tasks, worker_pool

    def piece(i, part):
        part["icp_runs"] += i
        part["icp_runs_by_kind"]["k"] = part["icp_runs_by_kind"].get("k", 0) + 1
        part["seconds"]["scoring"] += 0.5
        return i * i

    for threads in (1, 2, 3):
        stats = task_stats()
        with worker_pool(threads) as pool:
            assert (pool is None) == (threads == 1)
            assert run_tasks(pool, piece, list(range(10)), stats) == [i * i for i in range(10)]
            assert run_tasks(pool, piece, [3, 4], stats) == [9, 16]
        assert stats["icp_runs"] == 45 + 7 and stats["icp_runs_by_kind"] == {"k": 12}
        assert stats["seconds"]["scoring"] == 6.0

    def fails(i, part):
        if i == 2:
            raise RuntimeError("piece 2 failed")
        return i

    with worker_pool(2) as pool, pytest.raises(RuntimeError, match="piece 2"):
        run_tasks(pool, fails, [0, 1, 2, 3])
    with pytest.raises(ValueError, match="threads"):
        with worker_pool(0):
            pass
