"""Open3D's RANSAC plane (``segment_plane``), seeded and on one thread: one seed, one plane.

Open3D evaluates its RANSAC samples on all its threads (``o3d.utility.get_max_threads``: every
core, whatever ``OMP_NUM_THREADS`` says) and, unless ``probability`` is 1, stops once the best plane
so far makes a better one unlikely; which samples were evaluated by then, and so the plane, depends
on the threads' timing. Seen in a full test run on 2 cores: two noise characterisations of one patch
with the same seed found 4900 and 4829 inliers. On one thread the samples are evaluated in order and
the plane depends on the seed alone. The workflow's outputs stay the same: its noise
characterisation (real patches and simulated), recomputed, equals the last full default run's, and
the `paper` seabed planes of three dev scenes equal the former calls'.

The seed and the thread count are Open3D's process-wide settings: a lock keeps two threads of one
process from interleaving them, and the thread count is put back afterwards.
"""

from __future__ import annotations

import threading

import numpy as np
import open3d as o3d

__all__ = ["segment_plane"]

_LOCK = threading.Lock()


def segment_plane(points: np.ndarray, distance_m: float, ransac_n: int, iterations: int, seed: int,
                  probability: float = 0.99999999) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC plane of points (N, 3) in any frame (m): Open3D ``segment_plane`` with inlier distance
    `distance_m` (m), `ransac_n` points per sample, at most `iterations` samples and early stopping at
    `probability` (Open3D's default; 1: every sample), seeded with `seed`, on one thread.

    Returns (plane [a, b, c, d] with a x + b y + c z + d = 0 (float64, 4), inlier indices (K,) int64)."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64)))
    with _LOCK:
        threads = o3d.utility.get_max_threads()
        o3d.utility.set_max_threads(1)
        try:
            o3d.utility.random.seed(int(seed))
            plane, inliers = pcd.segment_plane(distance_threshold=float(distance_m), ransac_n=int(ransac_n),
                                               num_iterations=int(iterations), probability=float(probability))
        finally:
            o3d.utility.set_max_threads(threads)
    return np.asarray(plane, dtype=np.float64), np.asarray(inliers, dtype=np.int64)
