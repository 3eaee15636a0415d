"""Registration of class models to scene crops with Open3D ICP, with guards for degenerate input.

Poses are (R (3,3), t (3,)) taking canonical object coordinates into the detector's local scene frame:
p_scene = R p_canonical + t (metres). ICP works on float64 Open3D point clouds.

* `icp_point_to_point`: the source study's step: the template (source) moved onto the window points
  (target) by point-to-point ICP from a centroid alignment.
* `icp_scene_to_model`: the `ours` step: the scene crop (source) registered onto the evenly sampled
  mesh surface (target, with normals) by point-to-plane ICP with a Tukey robust kernel, coarse to fine
  (a list of (max correspondence distance m, iterations, voxel m) stages). Registering the scene to
  the model means extra scene points (neighbours, clutter) are rejected by the kernel, while model
  parts the sonar did not see cost nothing.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from . import window_icp

reg = o3d.pipelines.registration

#: ICP stops when the relative change of fitness and of inlier RMSE between iterations falls below these.
ICP_RELATIVE_FITNESS = 1e-6
ICP_RELATIVE_RMSE = 1e-6
#: Largest deviation of a result's rotation block from a proper rotation (|det - 1|, |R^T R - I|).
ROTATION_TOLERANCE = 1e-3
#: Fewest points (or ICP correspondences) that fix a rigid 3D transform.
MIN_RIGID_POINTS = 3


@dataclass
class IcpResult:
    """Outcome of one ICP run: pose R (3,3), t (3,) m (canonical -> scene), Open3D fitness (share of
    source points with a correspondence, 0..1) and inlier RMSE (m) of the last stage."""

    R: np.ndarray
    t: np.ndarray
    fitness: float
    rmse_m: float


def degenerate_reason(points: np.ndarray, min_points: int, min_spread_m: float = 0.02,
                      min_thickness_m: float = 0.0) -> str | None:
    """Why `points` (K,3) cannot support a rigid 6-DOF fit, or None if they can.

    Reasons: fewer than `min_points` (at least 3) points, non-finite values, a collinear set (the
    second principal spread, in metres, below `min_spread_m`) or, when `min_thickness_m` > 0, a planar
    set (the third principal spread below it: a patch of seabed or any flat surface).
    """
    p = np.asarray(points, dtype=np.float64)
    need = max(MIN_RIGID_POINTS, int(min_points))
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < need:
        return f"too few points ({len(p)} < {need})"
    if not np.all(np.isfinite(p)):
        return "non-finite coordinates"
    c = p - p.mean(0)
    ev = np.linalg.eigvalsh(c.T @ c / len(p))
    spread = np.sqrt(np.clip(ev, 0, None))
    if spread[1] < min_spread_m:
        return f"collinear points (second spread {spread[1]:.4f} m < {min_spread_m} m)"
    if min_thickness_m > 0 and spread[0] < min_thickness_m:
        return f"planar points (thickness {spread[0]:.4f} m < {min_thickness_m} m)"
    return None


def point_cloud(points: np.ndarray, normals: np.ndarray | None = None) -> o3d.geometry.PointCloud:
    """An Open3D point cloud (float64) of points (K,3) in any frame (m), with normals (K,3) if given."""
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(points, dtype=np.float64)))
    if normals is not None:
        pcd.normals = o3d.utility.Vector3dVector(np.ascontiguousarray(normals, dtype=np.float64))
    return pcd


def is_rigid_transform(T: np.ndarray) -> bool:
    """Whether a 4x4 transform (ICP output) is finite and its rotation block a proper rotation within
    `ROTATION_TOLERANCE` (determinant 1, orthonormal columns): no reflection, shear or NaN.

    Computed on Python floats (the determinant as the triple product of the rows): called after every
    ICP stage, where numpy's per-call overhead on a 3x3 block cost more than the ICP of a small crop."""
    rows = np.asarray(T, dtype=np.float64).tolist()
    if not all(math.isfinite(v) for row in rows for v in row):
        return False
    (a, b, c), (d, e, f), (g, h, i) = (row[:3] for row in rows[:3])
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    if abs(det - 1.0) >= ROTATION_TOLERANCE:
        return False
    cols = ((a, d, g), (b, e, h), (c, f, i))
    for j in range(3):
        for k in range(j, 3):
            u, v = cols[j], cols[k]
            dot = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
            if abs(dot - (1.0 if j == k else 0.0)) >= ROTATION_TOLERANCE:
                return False
    return True


@functools.lru_cache(maxsize=64)
def convergence(max_iter: int):
    """Open3D ICP convergence criteria: `max_iter` iterations at most, stopping earlier at the relative
    tolerances `ICP_RELATIVE_FITNESS` and `ICP_RELATIVE_RMSE` (one shared object per `max_iter`:
    registration_icp only reads it)."""
    return reg.ICPConvergenceCriteria(ICP_RELATIVE_FITNESS, ICP_RELATIVE_RMSE, int(max_iter))


@functools.lru_cache(maxsize=64)
def _point_to_plane_tukey(k_m: float):
    """Point-to-plane estimation with a Tukey kernel of width k_m (m), one shared object per width
    (registration_icp only reads it)."""
    return reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=float(k_m)))


@dataclass(frozen=True)
class IcpPoints:
    """Points (K,3, any frame, m) prepared once for many `icp_point_to_point` runs: their
    centroid (3,) and `degenerate_reason` under the checks they were prepared for (None: usable).

    The `paper` variant registers every template view onto every window: this checks and centres
    each template once, not once per window, and each window once, not once per template."""

    points: np.ndarray
    centroid: np.ndarray
    reason: str | None

    @classmethod
    def of(cls, points: np.ndarray, min_points: int = 10, min_thickness_m: float = 0.0) -> IcpPoints:
        """`points` (kept as given) checked by `degenerate_reason(points, min_points,
        min_thickness_m=...)`, and centred (the centroid only for usable points; NaN otherwise)."""
        reason = degenerate_reason(points, min_points, min_thickness_m=min_thickness_m)
        return cls(points, points.mean(0) if reason is None else np.full(3, np.nan), reason)


def icp_point_to_point(template: np.ndarray | IcpPoints, window: np.ndarray | IcpPoints, max_corr_m: float,
                       max_iter: int, R0: np.ndarray | None = None, min_points: int = 10,
                       min_thickness_m: float = 0.0, grid=None) -> IcpResult | None:
    """The source study's registration: template (canonical, (K,3)) onto window points ((M,3), scene frame).

    Initial pose: rotation R0 (identity by default) and the translation that puts the template's
    centroid on the window's centroid; then point-to-point ICP (`max_corr_m` correspondence distance,
    `max_iter` iterations): Open3D's `registration_icp`, or, with `grid` (a `window_icp.WindowGrid` of
    the window points), the same algorithm compiled on that grid. Returns None for degenerate input
    (fewer than `min_points`, collinear or non-finite points; a window thinner than
    `min_thickness_m`), a non-finite result or one without correspondences. Either input may be an
    `IcpPoints`, checked and centred once for many runs (with its own `min_points` and
    `min_thickness_m`, which replace the arguments for it).
    """
    if not isinstance(template, IcpPoints):
        template = IcpPoints.of(template, min_points)
    if template.reason:
        return None
    if not isinstance(window, IcpPoints):
        window = IcpPoints.of(window, min_points, min_thickness_m)
    if window.reason:
        return None
    R0 = np.eye(3) if R0 is None else np.asarray(R0, dtype=np.float64)
    T0 = np.eye(4)
    T0[:3, :3] = R0
    T0[:3, 3] = window.centroid - R0 @ template.centroid
    template, window = template.points, window.points
    if grid is not None:
        try:
            T, fitness, rmse, n_corr = window_icp.icp(template, grid, T0, max_corr_m, max_iter,
                                                      ICP_RELATIVE_FITNESS, ICP_RELATIVE_RMSE)
        except np.linalg.LinAlgError:  # an SVD that did not converge: non-finite points
            return None
    else:
        res = reg.registration_icp(point_cloud(template), point_cloud(window), float(max_corr_m), T0,
                                   reg.TransformationEstimationPointToPoint(), convergence(max_iter))
        T, fitness, rmse = np.asarray(res.transformation), float(res.fitness), float(res.inlier_rmse)
        n_corr = len(res.correspondence_set)
    if not is_rigid_transform(T) or n_corr < MIN_RIGID_POINTS:
        return None
    return IcpResult(T[:3, :3].copy(), T[:3, 3].copy(), fitness, rmse)


class SurfaceTarget:
    """A model surface (canonical points + normals) ready to be an ICP target (one Open3D cloud)."""

    def __init__(self, points: np.ndarray, normals: np.ndarray):
        self.points = np.asarray(points, dtype=np.float64)
        self.pcd = point_cloud(self.points, normals)


class SceneSource:
    """Scene points prepared once as ICP sources: the full cloud and its voxel-thinned versions."""

    def __init__(self, points: np.ndarray, min_points: int = 10):
        self.points = np.asarray(points, dtype=np.float64)
        self.min_points = int(min_points)
        self.reason = degenerate_reason(self.points, min_points)
        self._full = point_cloud(self.points) if self.reason is None else None
        self._thin: dict = {}
        self._arrays: dict = {}

    def at(self, voxel_m: float) -> o3d.geometry.PointCloud:
        """The source cloud thinned to `voxel_m` (the full cloud if thinning leaves too few points)."""
        if not voxel_m or voxel_m <= 0:
            return self._full
        if voxel_m not in self._thin:
            thin = self._full.voxel_down_sample(float(voxel_m))
            self._thin[voxel_m] = thin if len(thin.points) >= self.min_points else self._full
        return self._thin[voxel_m]

    def points_at(self, voxel_m: float) -> np.ndarray:
        """The points (K,3) of `at(voxel_m)` as a float64 array (scene frame, m)."""
        if voxel_m not in self._arrays:
            self._arrays[voxel_m] = np.asarray(self.at(voxel_m).points)
        return self._arrays[voxel_m]


def icp_scene_to_model(scene_pts, target, R0: np.ndarray, t0: np.ndarray, stages, tukey_k_factor: float = 0.5,
                       min_points: int = 10) -> IcpResult | None:
    """Register scene points onto a model surface, starting from pose (R0, t0).

    scene_pts: (K,3) points in the scene frame, or a prepared `SceneSource`. target: a `SurfaceTarget`
    or a list of them, one per stage (e.g. a coarser surface sampling for the coarse stage).
    stages: sequence of (max correspondence distance m, max iterations, source voxel m or 0); each
    stage runs point-to-plane ICP with a Tukey kernel of width tukey_k_factor x the distance. The
    pose returned maps canonical coordinates into the scene. Returns None for degenerate input (see
    `degenerate_reason`), too few correspondences, or a non-finite or improper result.
    """
    src_all = scene_pts if isinstance(scene_pts, SceneSource) else SceneSource(scene_pts, min_points)
    if src_all.reason is not None:
        return None
    targets = target if isinstance(target, (list, tuple)) else [target] * len(stages)
    R0 = np.asarray(R0, dtype=np.float64)
    t0 = np.asarray(t0, dtype=np.float64)
    if not (np.all(np.isfinite(R0)) and np.all(np.isfinite(t0))):
        return None
    # Scene -> canonical is the inverse pose.
    T = np.eye(4)
    T[:3, :3] = R0.T
    T[:3, 3] = -R0.T @ t0
    res = None
    for (max_corr, n_iter, voxel), tgt in zip(stages, targets):
        src = src_all.at(voxel)
        est = _point_to_plane_tukey(float(tukey_k_factor * max_corr))
        res = reg.registration_icp(src, tgt.pcd, float(max_corr), T, est, convergence(int(n_iter)))
        T_new = np.asarray(res.transformation)
        if not is_rigid_transform(T_new) or len(res.correspondence_set) < min_points:
            return None
        T = T_new
    if res is None:
        return None
    Rinv, tinv = T[:3, :3], T[:3, 3]
    R = Rinv.T
    return IcpResult(R.copy(), -R @ tinv, float(res.fitness), float(res.inlier_rmse))
