"""Scores of a posed class model against the scene: two-way inlier fractions, robust RMSE, plausibility.

All positions in the detector's local scene frame (metres); a pose (R, t) maps canonical object
coordinates into it. Definitions (per hypothesis):

* candidate points: object-candidate scene points (above the seabed) inside the posed evaluation box
  grown by `candidate_box_margin_m`;
* inliers: candidates closer than `inlier_m` to the posed mesh (exact point-to-mesh distance);
* f_s (scene -> model): inliers / candidates, both counted only over points not yet explained by an
  accepted object, so a clutter blob or a neighbour inside the box lowers it, while an object already
  accepted (the ring on top of this one) does not;
* f_t (model -> scene): share of the template points that have a scene point within `coverage_m`, best
  over the class's template views (each view is a real scan with the sensor's occlusion pattern, so
  template parts the sonar cannot see are not asked for); tumbled poses, which the upright template
  scans do not cover, use virtual views instead (the posed mesh ray-cast from nadir and oblique
  directions, `virtual_view_incidences_deg`, `virtual_views`); template points hidden under accepted
  objects are not asked for (`hidden_under`);
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
        """The rotation R as a unit quaternion (w, x, y, z)."""
        return matrix_to_quat(self.R)


def up_tilt_rad(model, R: np.ndarray) -> float:
    """Tilt (rad) of the object from a resting pose: the smallest angle between one of its class's
    up axes (`model.up_axes`; z for most classes, each leg for a tetrapod, which rests on any three)
    posed by R and the scene's z axis."""
    up = (R @ model.up_axes.T)[2]
    return float(np.arccos(np.clip(up.max(), -1.0, 1.0)))


def view_points(views: list, voxel_m: float) -> list:
    """Template views (canonical frame, m) thinned to one point (the first) per `voxel_m` voxel; empty
    views are left out."""
    out = []
    for v in views:
        if len(v) == 0:
            continue
        k = np.floor(v / voxel_m).astype(np.int64)
        _, first = np.unique(k, axis=0, return_index=True)
        out.append(v[np.sort(first)])
    return out


def view_directions(incidences_deg, n_azimuth: int) -> np.ndarray:
    """Unit viewing directions (K,3), pointing down: one per incidence angle off nadir (deg; 0 = nadir,
    one direction) from `n_azimuth` evenly spread sides."""
    out = []
    for inc in np.deg2rad(incidences_deg):
        azs = [0.0] if inc == 0 else np.arange(n_azimuth) * 2 * np.pi / n_azimuth
        for az in azs:
            out.append([np.sin(inc) * np.cos(az), np.sin(inc) * np.sin(az), -np.cos(inc)])
    return np.asarray(out)


def virtual_views(model, R: np.ndarray, t: np.ndarray, cell_m: float, directions: np.ndarray) -> list:
    """Point sets (scene frame, m) of the posed mesh as seen along each of `directions` (K,3).

    For a pose the template scans do not cover (a tumbled object), each view casts a grid of parallel
    rays (spacing `cell_m`, m) from that direction at the posed mesh (Open3D ray casting on the
    canonical mesh, rays turned into its frame) and keeps the first hits: the surface a sonar looking
    from there could see, self-occlusion included. The scorer uses nadir and oblique looks from several
    sides (`view_directions`), like the template views' across-track offsets.
    """
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
        dist = model.cast_down((o - t) @ R, R.T @ d)
        hit = np.isfinite(dist)
        out.append(o[hit] + dist[hit, None] * d)
    return out


def hidden_under(points: np.ndarray, boxes, footprint_margin_m: float, above_bottom_m: float) -> np.ndarray:
    """Boolean (K,) of points (K,3, m) lying under one of the boxes [x,y,z,l,w,h,yaw] (m, rad): inside its
    footprint grown by `footprint_margin_m` and no higher than `above_bottom_m` above its bottom, i.e.
    hidden from above by that object."""
    out = np.zeros(len(points), dtype=bool)
    for b in boxes:
        dx, dy = points[:, 0] - b[0], points[:, 1] - b[1]
        c, s = np.cos(b[6]), np.sin(b[6])
        u, v = dx * c + dy * s, -dx * s + dy * c
        out |= (np.abs(u) <= 0.5 * b[3] + footprint_margin_m) & (np.abs(v) <= 0.5 * b[4] + footprint_margin_m) & \
               (points[:, 2] <= b[2] - 0.5 * b[5] + above_bottom_m)
    return out


@dataclass
class SceneIndex:
    """The scene points a hypothesis is scored against (detector's local frame, m).

    pts (N,3): object-candidate points (above the seabed); active (N,) bool: not yet explained by an
    accepted object; tree_xy: cKDTree over pts[:, :2]; all_xyz (M,3): every scene point, seabed
    included (the coverage term); all_tree_xy: cKDTree over all_xyz[:, :2].
    """

    pts: np.ndarray
    active: np.ndarray
    tree_xy: cKDTree
    all_xyz: np.ndarray
    all_tree_xy: cKDTree


def _asked(points: np.ndarray, occluders, params: dict) -> np.ndarray:
    """Boolean (K,): template points (scene frame) the sonar could see, i.e. not hidden under an occluder."""
    if not len(occluders):
        return np.ones(len(points), dtype=bool)
    return ~hidden_under(points, occluders, params["hidden_footprint_margin_m"], params["hidden_above_bottom_m"])


def _coverage_upright(views: list, R, t, ltree: cKDTree, occluders, params: dict) -> float:
    """f_t of an upright pose: best over the thinned template views (canonical, posed by R, t) of the share
    of asked points with a scene point within coverage_m."""
    cov = params["coverage_m"]
    allv = np.concatenate(views) @ R.T + t
    dd, _ = ltree.query(allv, k=1, distance_upper_bound=cov)
    hit = np.isfinite(dd)
    asked = _asked(allv, occluders, params)
    bounds = np.cumsum([0] + [len(v) for v in views])
    floor = params["coverage_asked_min_frac"]
    return float(max((hit[a:b] & asked[a:b]).sum() / max(asked[a:b].sum(), floor * (b - a), 1.0)
                     for a, b in zip(bounds[:-1], bounds[1:])))


def _coverage_virtual(model, R, t, ltree: cKDTree, occluders, params: dict) -> float:
    """f_t of a tumbled pose: best over the virtual views of the posed mesh (see `virtual_views`)."""
    cov = params["coverage_m"]
    floor = params["coverage_asked_min_frac"]
    dirs = view_directions(params["virtual_view_incidences_deg"], int(params["virtual_view_azimuths_n"]))
    best = 0.0
    for pv in virtual_views(model, R, t, params["coverage_voxel_m"], dirs):
        if len(pv) < params["virtual_view_min_points_n"]:
            continue
        dd, _ = ltree.query(pv, k=1, distance_upper_bound=cov)
        asked = _asked(pv, occluders, params)
        best = max(best, float((np.isfinite(dd) & asked).sum() / max(asked.sum(), floor * len(pv), 1.0)))
    return best


def score_hypothesis(model, views: list, R, t, scene: SceneIndex, params: dict, rmse_max_m: float,
                     occluders=()) -> Hypothesis:
    """Score the pose (R (3,3), t (3,) m: canonical -> local scene frame) of `model` against `scene`.

    views: the class's template views thinned to coverage_voxel_m (`view_points`), for upright poses.
    rmse_max_m: the class's RMSE limit (m). occluders: boxes [x,y,z,l,w,h,yaw] of accepted objects;
    template points hidden under them are not asked for (f_t counts only the others). Returns a
    Hypothesis with the scores filled in (score 0 when no candidate point exists); the thresholds are
    the `params` keys named in the module doc and in `params.DESCRIPTIONS`.
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    box = canonical_box(model.vertices, t, matrix_to_quat(R), model.symmetry_order)
    h = Hypothesis(cls=model.cls, R=R, t=t, box=box)
    reach = 0.5 * np.hypot(box[3], box[4]) + params["score_reach_margin_m"]
    near = np.asarray(scene.tree_xy.query_ball_point(box[:2], reach), dtype=np.int64)
    if len(near) == 0:
        return h
    near.sort()
    inbox = points_in_box(scene.pts[near], box, params["candidate_box_margin_m"])
    cand = near[inbox]
    if len(cand) == 0:
        return h
    d = model.distance((scene.pts[cand] - t) @ R)
    inl = d < params["inlier_m"]
    h.cand, h.inl = cand, inl
    h.rmse_m = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else 1.0  # no inlier: 1 m, beyond any rmse_max
    h.upright = up_tilt_rad(model, R) <= np.deg2rad(params["upright_tilt_max_deg"])
    # Coverage against the scene points (seabed included) around the object, in a small local tree.
    local = scene.all_tree_xy.query_ball_point(box[:2], reach + params["coverage_m"])
    if len(local) > 0:
        local_pts = scene.all_xyz[np.sort(np.asarray(local, dtype=np.int64))]
        local_pts = local_pts[np.abs(local_pts[:, 2] - box[2]) <= 0.5 * box[5] + params["coverage_z_band_m"]]
        if len(local_pts) > 0:
            ltree = cKDTree(local_pts)
            h.f_t = (_coverage_upright(views, R, t, ltree, occluders, params) if h.upright
                     else _coverage_virtual(model, R, t, ltree, occluders, params))
    rescore(h, scene.active, rmse_max_m)
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
