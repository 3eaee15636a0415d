"""The batched point-to-plane ICP on a nearest-sample grid (sonardet.detect.model_based.grid_icp):
its nearest-sample bound, its arithmetic against a plain reference on the same correspondences, its
poses against Open3D's ICP, and its behaviour on degenerate input."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from sonardet.detect.model_based.grid_icp import NearestSurfaceGrid, icp_point_to_plane_starts


def box_surface(size=(1.0, 0.7, 0.5), step_m: float = 0.04):
    """Samples (M,3) and outward normals (M,3) of the faces of an axis-aligned box, base centre at the origin."""
    sx, sy, sz = size
    pts, nrm = [], []
    for axis, half in ((0, sx / 2), (1, sy / 2), (2, sz / 2)):
        others = [a for a in range(3) if a != axis]
        ext = [size[a] for a in others]
        u = np.arange(-ext[0] / 2, ext[0] / 2 + 1e-9, step_m)
        v = np.arange(-ext[1] / 2, ext[1] / 2 + 1e-9, step_m)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        for sign in (-1.0, 1.0):
            p = np.zeros((uu.size, 3))
            p[:, others[0]] = uu.ravel()
            p[:, others[1]] = vv.ravel()
            p[:, axis] = sign * half
            n = np.zeros_like(p)
            n[:, axis] = sign
            pts.append(p)
            nrm.append(n)
    p = np.concatenate(pts)
    p[:, 2] += sz / 2
    return p, np.concatenate(nrm)


def pose(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = t
    return T


def reference_icp(src, T, grid, max_corr, k, n_iter, tol=1e-6, exact=True):
    """The same algorithm in plain NumPy, correspondences from `grid.nearest_sample` (test oracle)."""
    P, N = grid.points, grid.normals

    def corr(T):
        m = src @ T[:3, :3].T + T[:3, 3]
        j = grid.nearest_sample(m, exact)
        d = np.where(j >= 0, np.linalg.norm(m - P[np.maximum(j, 0)], axis=1), np.inf)
        ok = d < max_corr
        return m, j, ok, ok.mean(), np.sqrt((d[ok] ** 2).mean()) if ok.any() else 0.0

    m, j, ok, fit, err = corr(T)
    for _ in range(n_iter):
        mm, q, n = m[ok], P[j[ok]], N[j[ok]]
        r = ((mm - q) * n).sum(1)
        w = np.where(np.abs(r) <= k, (1 - (r / k) ** 2) ** 2, 0.0)
        J = np.hstack([np.cross(mm, n), n])
        A = (J * w[:, None]).T @ J
        b = -(J * w[:, None]).T @ r
        x = np.linalg.solve(A, b)
        U = np.eye(4)
        U[:3, :3] = Rotation.from_euler("ZYX", [x[2], x[1], x[0]]).as_matrix()
        U[:3, 3] = x[3:]
        T = U @ T
        m, j, ok, fit2, err2 = corr(T)
        done = abs(fit2 - fit) < tol and abs(err2 - err) < tol
        fit, err = fit2, err2
        if done:
            break
    return T, fit, err


@pytest.fixture(scope="module")
def box():
    p, n = box_surface()
    return p, n, NearestSurfaceGrid(p, n, cell_m=0.02, margin_m=0.4)


def test_grid_nearest_sample_against_the_exact_nearest(box):
    p, _, grid = box
    rng = np.random.default_rng(0)
    q = rng.uniform(grid.lo, grid.lo + np.array(grid.shape) * grid.cell_m, size=(20000, 3))
    j = grid.nearest_sample(q)
    assert (j >= 0).all()
    d_grid = np.linalg.norm(q - p[j], axis=1)
    d_exact, _ = cKDTree(p).query(q)
    assert np.all(d_grid >= d_exact - 1e-12)
    assert (d_grid == d_exact).mean() > 0.99  # refined by descent: the exact nearest for nearly all
    # The cell's own sample alone: within two cell diagonals of the exact nearest distance.
    d_cell = np.linalg.norm(q - p[grid.nearest_sample(q, exact=False)], axis=1)
    assert np.all(d_cell <= d_exact + 2 * np.sqrt(3) * grid.cell_m + 1e-12)
    assert np.all(d_grid <= d_cell + 1e-12)
    # Points of the samples' own cells get a sample of that cell.
    assert np.all(np.linalg.norm(p - p[grid.nearest_sample(p)], axis=1) <= np.sqrt(3) * grid.cell_m)
    # Off the grid: -1.
    assert (grid.nearest_sample(grid.lo[None] - 0.01) == -1).all()


@pytest.mark.parametrize("exact", [True, False])
def test_compiled_icp_equals_the_plain_reference_on_the_same_correspondences(box, exact):
    p, _, grid = box
    rng = np.random.default_rng(1)
    src = p[rng.choice(len(p), 300, replace=False)] + rng.normal(0, 0.005, (300, 3))
    starts = np.stack([pose(rng.normal(0, 0.15, 3), rng.normal(0, 0.08, 3)) for _ in range(6)])
    T, fit, err, n = icp_point_to_plane_starts(src, starts, grid, 0.3, 0.15, 10, exact=exact)
    for s in range(len(starts)):
        T_ref, fit_ref, err_ref = reference_icp(src, starts[s], grid, 0.3, 0.15, 10, exact=exact)
        np.testing.assert_allclose(T[s], T_ref, atol=1e-9)
        assert fit[s] == pytest.approx(fit_ref, abs=1e-12)
        assert err[s] == pytest.approx(err_ref, abs=1e-12)
        assert n[s] == round(fit_ref * len(src))


def test_batched_starts_give_the_results_of_single_calls(box):
    p, _, grid = box
    rng = np.random.default_rng(2)
    src = p[rng.choice(len(p), 200, replace=False)]
    starts = np.stack([pose(rng.normal(0, 0.3, 3), rng.normal(0, 0.1, 3)) for _ in range(5)])
    T, fit, err, n = icp_point_to_plane_starts(src, starts, grid, 0.4, 0.2, 6)
    for s in range(len(starts)):
        T1, fit1, err1, n1 = icp_point_to_plane_starts(src, starts[s:s + 1], grid, 0.4, 0.2, 6)
        np.testing.assert_array_equal(T[s], T1[0])
        assert (fit[s], err[s], n[s]) == (fit1[0], err1[0], n1[0])


def test_recovers_a_known_pose_like_open3d(box):
    """A scene of the box's surface moved by a known pose: the grid ICP and Open3D's point-to-plane ICP
    with the same Tukey kernel, from the same perturbed start, both land on the true pose."""
    p, n, grid = box
    rng = np.random.default_rng(3)
    true = pose([0.05, -0.08, 0.6], [2.0, -1.0, 0.3])  # canonical -> scene
    sel = rng.choice(len(p), 400, replace=False)
    scene = p[sel] @ true[:3, :3].T + true[:3, 3] + rng.normal(0, 0.003, (400, 3))
    want = np.linalg.inv(true)  # scene -> canonical
    start = pose([0.04, 0.03, -0.1], [0.06, -0.05, 0.03]) @ want
    T, fit, err, _ = icp_point_to_plane_starts(scene, start[None], grid, 0.3, 0.15, 30)
    src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scene))
    tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p))
    tgt.normals = o3d.utility.Vector3dVector(n)
    reg = o3d.pipelines.registration
    est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=0.15))
    res = reg.registration_icp(src, tgt, 0.3, start, est, reg.ICPConvergenceCriteria(1e-6, 1e-6, 30))
    for got in (T[0], np.asarray(res.transformation)):
        rot_err = np.degrees(Rotation.from_matrix(got[:3, :3] @ want[:3, :3].T).magnitude())
        assert rot_err < 0.2
        assert np.linalg.norm(np.linalg.inv(got)[:3, 3] - true[:3, 3]) < 0.005
    assert fit[0] == pytest.approx(res.fitness, abs=0.01)
    assert err[0] == pytest.approx(res.inlier_rmse, abs=0.002)


def test_within_is_the_distance_test_of_the_class_models(box):
    """`within` against the same rule computed with an exact k-d tree (models.ClassModel.within): along
    the nearest sample's normal near the surface, to the sample farther out."""
    p, n, _ = box
    near = 0.06
    grid = NearestSurfaceGrid(p, n, cell_m=0.02, margin_m=0.2)
    rng = np.random.default_rng(4)
    q = p[rng.choice(len(p), 4000)] + rng.normal(0, 0.05, (4000, 3))
    d, j = cKDTree(p).query(q)
    dot = np.abs(np.einsum("ij,ij->i", q - p[j], n[j]))
    for dist in (0.02, 0.05, 0.1):
        want = np.where(d < near, dot, d) < dist
        got = grid.within(q, dist, near)
        assert (got == want).mean() > 0.995  # the grid's sample is the exact nearest for about 99 %
        assert got.sum() == pytest.approx(want.sum(), rel=0.01)
    with pytest.raises(ValueError, match="margin"):
        grid.within(q, 0.3, near)


def test_degenerate_input_leaves_the_start_and_stays_finite(box):
    p, _, grid = box
    far = p[:100] + [50.0, 0.0, 0.0]  # no correspondence at all
    start = np.eye(4)
    T, fit, err, n = icp_point_to_plane_starts(far, start[None], grid, 0.3, 0.15, 10)
    np.testing.assert_array_equal(T[0], start)
    assert fit[0] == 0.0 and err[0] == 0.0 and n[0] == 0
    top = p[np.isclose(p[:, 2], p[:, 2].max())][:200]  # one plane: the normal equations are singular
    T, fit, err, n = icp_point_to_plane_starts(top + [0, 0, 0.01], start[None], grid, 0.3, 0.15, 10)
    assert np.isfinite(T).all() and n[0] > 0
    T, fit, err, n = icp_point_to_plane_starts(np.full((5, 3), np.nan), start[None], grid, 0.3, 0.15, 10)
    assert n[0] == 0 and np.isfinite(T).all()
    T, *_ = icp_point_to_plane_starts(p[:10], np.zeros((0, 4, 4)), grid, 0.3, 0.15, 10)
    assert T.shape == (0, 4, 4)


def test_bad_arguments_are_refused(box):
    p, n, grid = box
    with pytest.raises(ValueError, match="margin"):
        icp_point_to_plane_starts(p[:10], np.eye(4)[None], grid, 0.5, 0.25, 5)
    with pytest.raises(ValueError, match="cell_m"):
        NearestSurfaceGrid(p, n, 0.0, 0.3)
    with pytest.raises(ValueError, match="non-empty"):
        NearestSurfaceGrid(np.zeros((0, 3)), np.zeros((0, 3)), 0.02, 0.3)
