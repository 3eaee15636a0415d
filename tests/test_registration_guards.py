"""Guards of the ICP results: `is_rigid_transform` accepts proper rotations and nothing else, as the
matrix test (det, R^T R) states it; the shared Open3D settings objects give the same ICP result."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sonardet.detect.model_based.registration import (
    ROTATION_TOLERANCE,
    SurfaceTarget,
    convergence,
    icp_scene_to_model,
    is_rigid_transform,
)


def _matrix_test(T: np.ndarray) -> bool:
    """The definition: finite, |det R - 1| and max |R^T R - I| below the tolerance."""
    if not np.all(np.isfinite(T)):
        return False
    R = T[:3, :3]
    return (abs(np.linalg.det(R) - 1.0) < ROTATION_TOLERANCE
            and float(np.abs(R.T @ R - np.eye(3)).max()) < ROTATION_TOLERANCE)


def test_rigid_transform_guard_matches_the_matrix_test():
    rng = np.random.default_rng(0)
    seen = {True: 0, False: 0}
    for k in range(400):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=k).as_matrix()
        T[:3, 3] = rng.normal(0, 100, 3)
        kind = k % 5
        if kind == 1:  # reflection
            T[:3, 0] *= -1
        elif kind == 2:  # shear or scale near and beyond the tolerance
            T[:3, :3] = T[:3, :3] @ (np.eye(3) + rng.uniform(-3, 3) * ROTATION_TOLERANCE * rng.normal(size=(3, 3)))
        elif kind == 3:
            T[rng.integers(0, 3), rng.integers(0, 4)] = [np.nan, np.inf, -np.inf][k % 3]
        got = is_rigid_transform(T)
        assert got == _matrix_test(T), (k, kind)
        seen[got] += 1
    assert seen[True] > 100 and seen[False] > 100


def test_shared_settings_objects_give_the_same_icp_result():
    """ICP from two starts with the cached criteria / estimation objects: each result equals a second
    run (no state kept between calls; to 1e-9, since Open3D's multi-threaded sums may differ in the last
    bit between runs), and the criteria object is one per iteration count."""
    rng = np.random.default_rng(1)
    u, v = np.meshgrid(np.linspace(-1, 1, 30), np.linspace(-1, 1, 30))
    model = np.c_[u.ravel(), v.ravel(), 0.3 * np.sin(2 * u.ravel()) * np.cos(3 * v.ravel())]
    normals = np.c_[-0.6 * np.cos(2 * u.ravel()) * np.cos(3 * v.ravel()),
                    0.9 * np.sin(2 * u.ravel()) * np.sin(3 * v.ravel()), np.ones(u.size)]
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    target = SurfaceTarget(model, normals)
    R_true = Rotation.from_euler("z", 0.1).as_matrix()
    scene = model[::3] @ R_true.T + [0.05, -0.03, 0.02] + rng.normal(0, 0.002, (len(model[::3]), 3))
    stages = [(0.3, 20, 0.0), (0.1, 10, 0.0)]
    first = [icp_scene_to_model(scene, target, np.eye(3), t0, stages) for t0 in (np.zeros(3), [0.02, 0, 0])]
    again = [icp_scene_to_model(scene, target, np.eye(3), t0, stages) for t0 in (np.zeros(3), [0.02, 0, 0])]
    for a, b in zip(first, again):
        assert np.allclose(a.R, b.R, rtol=0, atol=1e-9) and np.allclose(a.t, b.t, rtol=0, atol=1e-9)
        assert abs(a.rmse_m - b.rmse_m) < 1e-9
    assert np.allclose(first[0].R, R_true, atol=5e-3) and np.allclose(first[0].t, [0.05, -0.03, 0.02], atol=5e-3)
    assert convergence(12) is convergence(12) and convergence(12) is not convergence(8)
