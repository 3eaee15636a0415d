"""Scores of a posed class model against the scene: two-way inlier fractions, robust RMSE, plausibility.

All positions in the detector's local scene frame (metres); a pose (R, t) maps canonical object
coordinates into it. Definitions (per hypothesis):

* candidate points: object-candidate scene points (above the seabed) inside the posed evaluation box
  grown by `margin_m`;
* inliers: candidates closer than `inlier_m` to the posed mesh (exact point-to-mesh distance);
* f_s (scene -> model): inliers / candidates, both counted only over points not yet explained by an
  accepted object, so a clutter blob or a neighbour inside the box lowers it, while an object already
  accepted (the ring on top of this one) does not;
* f_t (model -> scene): share of the template points that have a scene point within `coverage_m`, best
  over the class's template views (each view is a real scan with the sensor's occlusion pattern, so
  template parts the sonar cannot see are not asked for); tumbled poses, which the upright template
  scans do not cover, use virtual views instead (the posed mesh ray-cast from nadir and 30/50 deg
  oblique directions, `virtual_views`); template points hidden under accepted objects are not asked for;
* rmse: RMS point-to-mesh distance of the inliers (m);
* score = f_t * f_s * (1 - (rmse / rmse_max)^2), in [0, 1], higher is better.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ...geometry import matrix_to_quat, points_in_box
from ...objects.catalog import canonical_box


@dataclass(eq=False)
class Hypothesis:
    """A posed class model with its scores. `cand` indexes the object-candidate point array; `inl`
    (bool, len(cand)) marks the inliers among them."""

    cls: str
    R: np.ndarray
    t: np.ndarray
    box: np.ndarray
    f_t: float = 0.0
    f_s: float = 0.0
    rmse_m: float = 1.0
    fitness: float = 0.0
    score: float = 0.0
    cand: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    inl: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    upright: bool = True
    round: int = 0
    seed_xy: np.ndarray | None = None
    n_refits: int = 0
    uid: int = -1

    @property
    def q(self) -> np.ndarray:
        return matrix_to_quat(self.R)


def up_tilt_rad(model, R: np.ndarray) -> float:
    """Tilt (rad) of the object from its resting pose: angle between the canonical z axis and the
    scene's z axis; for tetrapods the smallest over the four legs (any three legs can be the base)."""
    if model.cls.startswith("tetrapod"):
        from ...objects.meshes import tetrapod_leg_directions

        up = (R @ tetrapod_leg_directions().T)[2]
        return float(np.arccos(np.clip(up.max(), -1.0, 1.0)))
    return float(np.arccos(np.clip(R[2, 2], -1.0, 1.0)))


def view_points(model, voxel_m: float) -> list:
    """The class's template views thinned to one point per `voxel_m` voxel (cached on the model)."""
    key = ("_views_thin", voxel_m)
    cache = model.__dict__.setdefault("_cache", {})
    if key not in cache:
        out = []
        for v in model.views:
            if len(v) == 0:
                continue
            k = np.floor(v / voxel_m).astype(np.int64)
            _, first = np.unique(k, axis=0, return_index=True)
            out.append(v[np.sort(first)])
        cache[key] = out
    return cache[key]


def _view_directions(max_incidence_deg=(0.0, 30.0, 50.0), n_azimuth: int = 4) -> np.ndarray:
    """Unit viewing directions (K,3), pointing down: nadir and oblique looks from n_azimuth sides."""
    out = []
    for inc in np.deg2rad(max_incidence_deg):
        azs = [0.0] if inc == 0 else np.arange(n_azimuth) * 2 * np.pi / n_azimuth
        for az in azs:
            out.append([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), -np.cos(inc)])
    return np.asarray(out)


VIEW_DIRECTIONS = _view_directions()


def virtual_views(model, R: np.ndarray, t: np.ndarray, cell_m: float) -> list:
    """Point sets (scene frame) of the posed mesh as seen along each of `VIEW_DIRECTIONS`.

    For a pose the template scans do not cover (a tumbled object), each view casts a grid of parallel
    rays (spacing `cell_m`) from that direction at the posed mesh (Open3D ray casting on the
    canonical mesh, rays turned into its frame) and keeps the first hits: the surface a sonar looking
    from there could see, self-occlusion included. Nadir, and 30 and 50 degrees off nadir from four
    sides, like the template views' across-track offsets.
    """
    v = model.vertices @ R.T + t
    c = 0.5 * (v.min(0) + v.max(0))
    r = 0.5 * float(np.linalg.norm(v.max(0) - v.min(0))) + cell_m
    g = np.arange(-r, r + 1e-9, cell_m)
    gu, gv = np.meshgrid(g, g)
    out = []
    for d in VIEW_DIRECTIONS:
        u = np.cross(d, [0.0, 1.0, 0.0] if abs(d[1]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        w = np.cross(d, u)
        o = c - 2.0 * r * d + gu.reshape(-1, 1) * u + gv.reshape(-1, 1) * w
        dist = model.cast_down((o - t) @ R, R.T @ d)
        hit = np.isfinite(dist)
        out.append(o[hit] + dist[hit, None] * d)
    return out


def top_surface_points(model, R: np.ndarray, t: np.ndarray, cell_m: float) -> np.ndarray:
    """Points (K,3, scene frame) of the posed mesh seen from straight above on a `cell_m` grid."""
    v = model.vertices @ R.T + t
    lo, hi = v[:, :2].min(0), v[:, :2].max(0)
    xs = np.arange(lo[0] + 0.5 * cell_m, hi[0], cell_m)
    ys = np.arange(lo[1] + 0.5 * cell_m, hi[1], cell_m)
    gx, gy = np.meshgrid(xs, ys)
    top = v[:, 2].max() + 1.0
    o = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, top)], 1)
    d = model.cast_down((o - t) @ R, R.T @ np.array([0.0, 0.0, -1.0]))
    hit = np.isfinite(d)
    p = o[hit].copy()
    p[:, 2] = top - d[hit]
    return p


def hidden_under(points: np.ndarray, boxes) -> np.ndarray:
    """Boolean (K,) of points (K,3) lying under one of the boxes [x,y,z,l,w,h,yaw]: inside its footprint
    (grown 5 cm) and no higher than 10 cm above its bottom, i.e. hidden from above by that object."""
    out = np.zeros(len(points), dtype=bool)
    for b in boxes:
        dx, dy = points[:, 0] - b[0], points[:, 1] - b[1]
        c, s = np.cos(b[6]), np.sin(b[6])
        u, v = dx * c + dy * s, -dx * s + dy * c
        out |= (np.abs(u) <= 0.5 * b[3] + 0.05) & (np.abs(v) <= 0.5 * b[4] + 0.05) & \
               (points[:, 2] <= b[2] - 0.5 * b[5] + 0.1)
    return out


def score_hypothesis(model, R, t, cls: str, pts: np.ndarray, active: np.ndarray, tree_xy, all_xyz, all_tree_xy,
                     params: dict,
                     rmse_max_m: float, occluders=(), upright_tilt_max_rad: float = np.deg2rad(30.0)) -> Hypothesis:
    """Score the pose (R, t) of `model` against object-candidate points `pts` (N,3).

    active (N,) bool marks points not yet explained; tree_xy is a cKDTree over pts[:, :2]; all_xyz (M,3)
    are every scene point (seabed included) and all_tree_xy a cKDTree over their xy, for the coverage
    term. Returns a Hypothesis with
    the scores filled in (score 0 when no candidate point exists). occluders: boxes of accepted objects;
    template points hidden under them are not asked for (f_t counts only the others).
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    box = canonical_box(model.vertices, t, matrix_to_quat(R), model.symmetry_order)
    h = Hypothesis(cls=cls, R=R, t=t, box=box)
    reach = 0.5 * np.hypot(box[3], box[4]) + 0.15
    near = np.asarray(tree_xy.query_ball_point(box[:2], reach), dtype=np.int64)
    if len(near) == 0:
        return h
    near.sort()
    inbox = points_in_box(pts[near], box, 0.1)
    cand = near[inbox]
    if len(cand) == 0:
        return h
    d = model.distance((pts[cand] - t) @ R)
    inl = d < params["inlier_m"]
    h.cand, h.inl = cand, inl
    h.rmse_m = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else 1.0
    h.upright = up_tilt_rad(model, R) <= upright_tilt_max_rad
    cov = params["coverage_m"]
    # Coverage against the scene points (seabed included) around the object, in a small local tree.
    local = all_tree_xy.query_ball_point(box[:2], reach + cov)
    if len(local) == 0:
        rescore(h, active, rmse_max_m)
        return h
    local_pts = all_xyz[np.sort(np.asarray(local, dtype=np.int64))]
    local_pts = local_pts[np.abs(local_pts[:, 2] - box[2]) <= 0.5 * box[5] + 0.3]
    if len(local_pts) == 0:
        rescore(h, active, rmse_max_m)
        return h
    ltree = cKDTree(local_pts)
    if h.upright:
        views = view_points(model, params["coverage_voxel_m"])
        allv = np.concatenate(views) @ R.T + t
        dd, _ = ltree.query(allv, k=1, distance_upper_bound=cov)
        hit = np.isfinite(dd)
        asked = ~hidden_under(allv, occluders) if len(occluders) else np.ones(len(allv), dtype=bool)
        bounds = np.cumsum([0] + [len(v) for v in views])
        h.f_t = float(max((hit[a:b] & asked[a:b]).sum() / max(asked[a:b].sum(), 0.2 * (b - a), 1.0)
                          for a, b in zip(bounds[:-1], bounds[1:])))
    else:
        best = 0.0
        for pv in virtual_views(model, R, t, params["coverage_voxel_m"]):
            if len(pv) < 10:
                continue
            dd, _ = ltree.query(pv, k=1, distance_upper_bound=cov)
            asked = ~hidden_under(pv, occluders) if len(occluders) else np.ones(len(pv), dtype=bool)
            best = max(best, float((np.isfinite(dd) & asked).sum() / max(asked.sum(), 0.2 * len(pv), 1.0)))
        h.f_t = best
    rescore(h, active, rmse_max_m)
    return h


def rescore(h: Hypothesis, active: np.ndarray, rmse_max_m: float) -> float:
    """Recompute f_s and the score of `h` given which candidate points are still unexplained."""
    if len(h.cand) == 0:
        h.f_s, h.score = 0.0, 0.0
        return 0.0
    a = active[h.cand]
    n_act = int(a.sum())
    h.f_s = float((h.inl & a).sum() / n_act) if n_act else 0.0
    q = max(0.0, 1.0 - (h.rmse_m / rmse_max_m) ** 2)
    h.score = float(h.f_t * h.f_s * q)
    return h.score


def new_fraction(h: Hypothesis, active: np.ndarray) -> float:
    """Share of the hypothesis' inliers not yet explained by accepted objects (0 without inliers)."""
    n = int(h.inl.sum())
    if n == 0:
        return 0.0
    return float((h.inl & active[h.cand]).sum() / n)
