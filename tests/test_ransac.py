"""sonardet.ransac: Open3D's seeded RANSAC plane on one thread."""

from __future__ import annotations

import numpy as np
import open3d as o3d

from sonardet.ransac import segment_plane


def _tilted_plane_with_outliers(n: int = 3000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-10, 10, size=(n, 2))
    z = 0.05 * xy[:, 0] - 0.02 * xy[:, 1] + 3.0 + rng.normal(0, 0.01, n)
    pts = np.column_stack([xy, z])
    out = rng.choice(n, n // 10, replace=False)
    pts[out, 2] += rng.uniform(0.5, 2.0, len(out))
    return pts


def test_plane_inliers_and_repeatability():
    pts = _tilted_plane_with_outliers()
    plane, inliers = segment_plane(pts, 0.05, 3, 500, seed=7)
    normal = plane[:3] / np.linalg.norm(plane[:3])
    expected = np.array([0.05, -0.02, -1.0]) / np.linalg.norm([0.05, -0.02, -1.0])
    assert abs(abs(normal @ expected) - 1.0) < 1e-4
    assert inliers.dtype == np.int64 and 0.85 * len(pts) < len(inliers) <= 0.9 * len(pts)
    for _ in range(5):  # the same seed, the same plane and inliers, bit for bit
        again, inl = segment_plane(pts, 0.05, 3, 500, seed=7)
        assert again.tobytes() == plane.tobytes() and np.array_equal(inl, inliers)


def test_open3d_thread_count_is_put_back():
    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(2)
    try:
        segment_plane(_tilted_plane_with_outliers(500), 0.05, 3, 100, seed=1)
        assert o3d.utility.get_max_threads() == 2
    finally:
        o3d.utility.set_max_threads(before)
