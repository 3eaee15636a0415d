"""The `paper` variant's compiled point-to-point ICP (sonardet.detect.model_based.window_icp) against
Open3D's `registration_icp` / `evaluate_registration`, which it reimplements on a search grid kept
across the window's three registration steps."""

import numpy as np
import open3d as o3d
import pytest

from sonardet.detect.model_based import window_icp
from sonardet.detect.model_based.registration import (
    ICP_RELATIVE_FITNESS,
    ICP_RELATIVE_RMSE,
    IcpPoints,
    convergence,
    icp_point_to_point,
    point_cloud,
)

TOL = (ICP_RELATIVE_FITNESS, ICP_RELATIVE_RMSE)

reg = o3d.pipelines.registration


def _surface(n: int, rng: np.random.Generator) -> np.ndarray:
    """n points (m) of a bumpy 3 x 3 m surface: no symmetry, so ICP has one answer."""
    xy = rng.uniform(-1.5, 1.5, (n, 2))
    z = 0.5 * np.sin(2 * xy[:, 0]) * np.cos(1.5 * xy[:, 1]) + 0.3 * xy[:, 0] ** 2
    return np.c_[xy, z]


def _yaw(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])


def _open3d_icp(tpl, win, T0, r, n_iter):
    res = reg.registration_icp(point_cloud(tpl), point_cloud(win), r, T0, reg.TransformationEstimationPointToPoint(),
                               convergence(n_iter))
    return np.asarray(res.transformation), res.fitness, res.inlier_rmse, len(res.correspondence_set)


def test_icp_and_evaluation_equal_open3d_to_rounding():
    """60 windows of 100-2500 noisy points, templates of 30-400 points from start poses up to 12 deg
    and 0.25 m off: the same pose, fitness, inlier RMSE and number of correspondences as Open3D, at
    both correspondence distances of the paper variant, and the same evaluation."""
    rng = np.random.default_rng(7)
    for _ in range(60):
        win = _surface(int(rng.integers(100, 2500)), rng) + rng.normal(0.0, 0.01, 3)
        tpl = _surface(int(rng.integers(30, 400)), rng)
        T0 = np.eye(4)
        T0[:3, :3] = _yaw(np.deg2rad(rng.uniform(-12, 12)))
        T0[:3, 3] = rng.uniform(-0.25, 0.25, 3)
        grid = window_icp.WindowGrid(win, 0.3)
        for r, n_iter in ((0.3, 30), (0.1, 20)):
            T, fit, rmse, n = window_icp.icp(tpl, grid, T0, r, n_iter, *TOL)
            T_o, fit_o, rmse_o, n_o = _open3d_icp(tpl, win, T0, r, n_iter)
            assert n == n_o
            assert np.abs(T - T_o).max() < 1e-9
            assert fit == pytest.approx(fit_o, abs=1e-12) and rmse == pytest.approx(rmse_o, abs=1e-9)
        ev = reg.evaluate_registration(point_cloud(tpl), point_cloud(win), 0.3, T)
        fit, rmse, n = window_icp.evaluate(tpl, grid, T, 0.3)
        assert n == len(ev.correspondence_set)
        assert fit == pytest.approx(ev.fitness, abs=1e-12) and rmse == pytest.approx(ev.inlier_rmse, abs=1e-12)


def test_far_start_without_correspondences_and_outliers_far_away():
    """A template 5 m from the window finds no correspondence and stops with fitness and RMSE 0, as
    Open3D does; a window with one sounding 100 m above the rest (a flier) gets coarser cells and the
    same fit as Open3D."""
    rng = np.random.default_rng(3)
    win = _surface(800, rng)
    tpl = _surface(150, rng)
    far = np.eye(4)
    far[:3, 3] = [5.0, 0.0, 0.0]
    grid = window_icp.WindowGrid(win, 0.3)
    T, fit, rmse, n = window_icp.icp(tpl, grid, far, 0.3, 30, *TOL)
    assert (n, fit, rmse) == (0, 0.0, 0.0) and np.array_equal(T, far)
    assert _open3d_icp(tpl, win, far, 0.3, 30)[1:] == (0.0, 0.0, 0)
    flier = np.vstack([win, [[0.0, 0.0, 100.0]]])
    coarse = window_icp.WindowGrid(flier, 0.01)
    assert coarse.cell_m > 0.01 and np.prod(coarse.dims) <= window_icp.MAX_CELLS
    start = np.eye(4)
    start[:3, 3] = [0.1, -0.05, 0.02]
    T, fit, rmse, n = window_icp.icp(tpl, coarse, start, 0.3, 30, *TOL)
    T_o, fit_o, rmse_o, n_o = _open3d_icp(tpl, flier, start, 0.3, 30)
    assert n == n_o and np.abs(T - T_o).max() < 1e-9 and rmse == pytest.approx(rmse_o, abs=1e-9)


def test_grid_holds_every_point_once_and_rejects_bad_input():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-2, 2, (500, 3))
    g = window_icp.WindowGrid(pts, 0.3)
    assert sorted(g.order.tolist()) == list(range(500))
    assert np.array_equal(g.sorted, pts[g.order]) and g.start[-1] == 500
    with pytest.raises(ValueError, match="non-empty finite"):
        window_icp.WindowGrid(np.array([[0.0, 0.0, np.nan]]), 0.3)
    with pytest.raises(ValueError, match="cell_m"):
        window_icp.WindowGrid(pts, 0.0)
    with pytest.raises(ValueError, match="correspondence distance"):
        window_icp.icp(pts[:10], g, np.eye(4), 0.0, 5, *TOL)


def test_the_paper_registration_gives_open3ds_fits():
    """`icp_point_to_point` from a centroid alignment, with and without the grid: the same result, and
    both decline a degenerate (planar) window alike."""
    rng = np.random.default_rng(11)
    for _ in range(10):
        win = _surface(1500, rng)
        tpl = _surface(200, rng) @ _yaw(0.1).T
        grid = window_icp.WindowGrid(win, 0.3)
        a = icp_point_to_point(tpl, win, 0.3, 30, min_thickness_m=0.03)
        b = icp_point_to_point(tpl, win, 0.3, 30, min_thickness_m=0.03, grid=grid)
        assert np.abs(a.R - b.R).max() < 1e-9 and np.abs(a.t - b.t).max() < 1e-9
        assert a.fitness == pytest.approx(b.fitness, abs=1e-12) and a.rmse_m == pytest.approx(b.rmse_m, abs=1e-9)
    flat = np.c_[rng.uniform(-1, 1, (300, 2)), np.zeros(300)]
    assert icp_point_to_point(tpl, flat, 0.3, 30, min_thickness_m=0.03) is None
    assert icp_point_to_point(tpl, flat, 0.3, 30, min_thickness_m=0.03,
                              grid=window_icp.WindowGrid(flat, 0.3)) is None


def test_points_prepared_once_register_as_the_arrays_do():
    """`IcpPoints` (checked and centred once for many runs, as the `paper` variant's templates and
    windows are) give the same fits, bit for bit, as the arrays, and decline the same inputs."""
    rng = np.random.default_rng(12)
    for _ in range(5):
        win = _surface(1500, rng)
        tpl = _surface(200, rng) @ _yaw(0.2).T
        grid = window_icp.WindowGrid(win, 0.3)
        a = icp_point_to_point(tpl, win, 0.3, 30, min_points=10, min_thickness_m=0.03, grid=grid)
        b = icp_point_to_point(IcpPoints.of(tpl, 10), IcpPoints.of(win, 10, 0.03), 0.3, 30, grid=grid)
        assert np.array_equal(a.R, b.R) and np.array_equal(a.t, b.t)
        assert (a.fitness, a.rmse_m) == (b.fitness, b.rmse_m)
    flat = np.c_[rng.uniform(-1, 1, (300, 2)), np.zeros(300)]
    prepared = IcpPoints.of(flat, 10, 0.03)
    assert prepared.reason.startswith("planar") and np.isnan(prepared.centroid).all()
    assert icp_point_to_point(IcpPoints.of(tpl, 10), prepared, 0.3, 30) is None
    assert IcpPoints.of(tpl[:5], 10).reason.startswith("too few points")
    assert icp_point_to_point(IcpPoints.of(tpl[:5], 10), IcpPoints.of(win, 10), 0.3, 30) is None
