"""Variant `paper`: the source study's pipeline, reconstructed.

1. seabed: one RANSAC plane (Open3D `segment_plane` on a seeded random subset of `ransac_sample_n`
   points); points more than `ground_min_height_m` above it are object candidates;
2. segmentation: per class, square sliding windows of side = class footprint x `window_scale` with
   `window_overlap`; windows holding fewer candidate points than `window_min_points_frac` x the
   class's median template-view size are skipped (counted in the statistics); flat windows (thinner
   than `window_min_thickness_m`: seabed, a planar patch) are not registered (degenerate input);
3. registration: one template view per class (`template_view`: the nadir view at yaw 0), without its
   points lower than `ground_min_height_m` above its base (the seabed removal takes those from a
   scan too), moved onto the window's points by centroid alignment + point-to-point ICP
   (`icp_max_corr_m`), then, when `icp_refine_iter` > 0, the same ICP continued with the tighter
   correspondence distance `icp_refine_corr_m` (so points of neighbouring objects in the window stop
   pulling the template off the object it has locked on); RMSE and fitness are those at `icp_max_corr_m`.
   The ICP is Open3D's algorithm, run compiled on one search grid of the window's points for all three
   steps (`icp_backend` "compiled", `window_icp`: the same poses as Open3D's to rounding, in
   less than half the time of the whole detection) or Open3D's `registration_icp` itself ("open3d").
   A window holding exactly the points of an earlier window of its class gets that window's fit
   (the same input gives the same result; counted as `windows_reused`, not as ICP runs;
   `reuse_identical_windows`);
4. acceptance: inlier RMSE <= `rmse_max_m[cls]` and fitness >= `fitness_min`; score =
   1 - rmse / rmse_max ('rmse': the study ranks by RMSE), fitness * (1 - rmse / rmse_max)
   ('fitness_rmse') or the share of template points within `score_corr_m` of a window point
   ('tight_fitness': how closely the template lies on the scan, comparable across classes);
5. duplicates: detections are taken by descending score; one is dropped when a kept detection of its
   class is closer than `duplicate_dist_m` (small enough that a stacked object, centred over the gap
   between the two below it, survives) or a kept detection of another class is closer than
   `duplicate_other_class_frac` x that class's radius (a smaller template fitted to part of a larger
   object: objects of different classes are not stacked).

Steps 1 to 3 do not depend on the parameters of steps 4 and 5 (`RANKING_KEYS`): settings that differ
only in those (the study's RMSE ranking and the ladder's tight-fitness ranking) can share one run's
seabed, windows and fits (`detect_paper_rankings`), each getting the detections it would get alone.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from ...geometry import matrix_to_quat
from ...objects.catalog import canonical_box
from .ground import seabed
from .params import per_class
from .proposals import sliding_windows, window_counts
from .registration import (
    ICP_RELATIVE_FITNESS,
    ICP_RELATIVE_RMSE,
    MIN_RIGID_POINTS,
    IcpPoints,
    IcpResult,
    convergence,
    icp_point_to_point,
    is_rigid_transform,
    point_cloud,
)
from . import window_icp
from .scoring import Hypothesis

SCORES = ("rmse", "fitness_rmse", "tight_fitness")
#: Parameters that act only after registration (acceptance, score, duplicate removal; module doc,
#: steps 4 and 5): settings equal in every other key register the same windows the same way.
RANKING_KEYS = ("rmse_max_m", "fitness_min", "score", "score_corr_m", "duplicate_dist_m",
                "duplicate_other_class_frac")
#: Counts of a run that the rankings of one shared run have in common (steps 1 to 3).
_SHARED_COUNTS = ("n_candidate_points", "windows", "windows_skipped", "windows_reused", "icp_runs", "icp_declined",
                  "capped")
_SHARED_STAGES = ("ground", "proposals", "registration")

log = logging.getLogger(__name__)


def paper_template(model, which: str) -> list:
    """Template point sets (canonical frame, m) the paper variant registers: 'nadir' one view (the one
    closest under the track at the smallest yaw with at least 3 points), 'all' every non-empty view."""
    if which == "all":
        return [v for v in model.views if len(v)]
    meta = model.view_meta
    order = sorted(range(len(model.views)), key=lambda k: (abs(meta["offset_m"][k]), abs(meta["yaw_rad"][k]), k))
    for k in order:
        if len(model.views[k]) >= MIN_RIGID_POINTS:
            return [model.views[k]]
    raise ValueError(f"class {model.cls!r} has no template view with points")


def thin(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point (the first) per `voxel_m` voxel, order kept (deterministic)."""
    if voxel_m <= 0 or len(points) == 0:
        return points
    k = np.floor(points / voxel_m).astype(np.int64)
    _, first = np.unique(k, axis=0, return_index=True)
    return points[np.sort(first)]


def refine_point_to_point(template: np.ndarray, window: np.ndarray, res: IcpResult, p: dict,
                          grid: window_icp.WindowGrid | None = None) -> IcpResult:
    """Continue a point-to-point ICP fit of `template` (canonical, (K,3)) on `window` ((M,3), scene
    frame) with the correspondence distance `icp_refine_corr_m` for `icp_refine_iter` iterations
    (Open3D's functions, or with `grid`, a `WindowGrid` of the window points, the compiled ones).

    Returns the refined pose with fitness and inlier RMSE (m) evaluated at `icp_max_corr_m` (the
    distance the RMSE thresholds are set for), or `res` unchanged when the refinement is off or
    finds fewer than 3 correspondences or an invalid transform.
    """
    if p["icp_refine_iter"] <= 0 or p["icp_refine_corr_m"] <= 0:
        return res
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = res.R, res.t
    if grid is not None:
        try:
            T, _, _, n_corr = window_icp.icp(template, grid, T, p["icp_refine_corr_m"], p["icp_refine_iter"],
                                             ICP_RELATIVE_FITNESS, ICP_RELATIVE_RMSE)
        except np.linalg.LinAlgError:
            return res
    else:
        reg = o3d.pipelines.registration
        src, tgt = point_cloud(template), point_cloud(window)
        r = reg.registration_icp(src, tgt, float(p["icp_refine_corr_m"]), T,
                                 reg.TransformationEstimationPointToPoint(), convergence(p["icp_refine_iter"]))
        T, n_corr = np.asarray(r.transformation), len(r.correspondence_set)
    if n_corr < MIN_RIGID_POINTS or not is_rigid_transform(T):
        return res
    if grid is not None:
        fitness, rmse, _ = window_icp.evaluate(template, grid, T, p["icp_max_corr_m"])
    else:
        ev = reg.evaluate_registration(src, tgt, float(p["icp_max_corr_m"]), T)
        fitness, rmse = float(ev.fitness), float(ev.inlier_rmse)
    return IcpResult(T[:3, :3].copy(), T[:3, 3].copy(), fitness, rmse)


def window_grid(window: np.ndarray, p: dict) -> window_icp.WindowGrid | None:
    """The `WindowGrid` of a window's points (M,3, scene frame) for every step of the registration
    (`icp_backend` "compiled"; cells of the larger correspondence distance), or None (backend
    "open3d", or an empty or non-finite window, which the registration declines anyway)."""
    if p["icp_backend"] != "compiled" or len(window) == 0 or not np.isfinite(window).all():
        return None
    return window_icp.WindowGrid(window, max(float(p["icp_max_corr_m"]), float(p["icp_refine_corr_m"])))


def tight_fitness(template: np.ndarray, window_tree: cKDTree, res: IcpResult, dist_m: float) -> float:
    """Share (0..1) of the posed template's points (K,3, canonical) with a window point within `dist_m` (m)."""
    if len(template) == 0:
        return 0.0
    d, _ = window_tree.query(template @ res.R.T + res.t, k=1, distance_upper_bound=dist_m)
    return float(np.mean(d < dist_m))


def is_duplicate(h, kept: list, radius_m: dict, p: dict) -> bool:
    """Whether hypothesis `h` duplicates one of the `kept` (better-scored) ones (see the module doc, step 5)."""
    for k in kept:
        d = float(np.hypot(*(h.box[:2] - k.box[:2])))
        lim = p["duplicate_dist_m"]
        if k.cls != h.cls:
            lim = max(lim, p["duplicate_other_class_frac"] * radius_m[k.cls])
        if d < lim:
            return True
    return False


def _class_windows(pts: np.ndarray, lo, hi, m, p: dict, stats: dict):
    """The sliding windows (K,4) of class model `m` over the rectangle [lo, hi] (m) that hold enough
    candidate points to be registered (all of them unless skip_empty_windows), at most `window_max_n`
    of them (those holding the most points, in window order; the rest counted in stats["capped"] and
    logged), and the window side (m)."""
    side = m.footprint_m * p["window_scale"]
    wins = sliding_windows(lo, hi, side, p["window_overlap"])
    counts = window_counts(pts[:, :2], wins)
    n_min = p["window_min_points_frac"] * float(np.median([len(v) for v in m.views]))
    run = counts >= n_min if p["skip_empty_windows"] else np.ones(len(wins), dtype=bool)
    stats["windows"] += len(wins)
    stats["windows_skipped"] += int((~run).sum())
    cap, n_run = int(p["window_max_n"]), int(run.sum())
    if n_run > cap:
        idx = np.flatnonzero(run)
        keep = np.sort(idx[np.argsort(-counts[idx], kind="stable")[:cap]])
        stats["capped"]["windows"] = stats["capped"].get("windows", 0) + n_run - cap
        log.warning("%s: %d windows to register; only the %d holding the most points are (window_max_n)", m.cls,
                    n_run, cap)
        run = np.zeros_like(run)
        run[keep] = True
    log.info("%s: %d windows of %.2f m, %d with too few points, %d capped, %d registered", m.cls, len(wins), side,
             len(wins) - n_run, n_run - int(run.sum()), int(run.sum()))
    return wins[run], side


def _best_fit(templates: list[IcpPoints], window: np.ndarray, p: dict, stats: dict):
    """The (IcpResult, template points) of the lowest RMSE over the templates (each checked and
    centred once for all windows) registered onto the window points (centroid alignment +
    point-to-point ICP + refinement), or None when every ICP declines."""
    stats["icp_runs"] += len(templates)
    win = IcpPoints.of(window, p["icp_min_points_n"], p["window_min_thickness_m"])
    if win.reason:  # every ICP would decline this window: no grid to build
        stats["icp_declined"] += len(templates)
        return None
    best = None
    grid = window_grid(window, p)
    for tpl in templates:
        res = icp_point_to_point(tpl, win, p["icp_max_corr_m"], p["icp_max_iter"], grid=grid)
        if res is None:
            stats["icp_declined"] += 1
            continue
        res = refine_point_to_point(tpl.points, window, res, p, grid)
        if best is None or res.rmse_m < best[0].rmse_m:
            best = (res, tpl.points)
    return best


def _hypothesis(cls: str, m, res: IcpResult, tpl: np.ndarray, window: np.ndarray, rmse_max: float,
                p: dict) -> Hypothesis:
    """An accepted fit as a scored Hypothesis (score: see the module doc, step 4)."""
    box = canonical_box(m.vertices, res.t, matrix_to_quat(res.R), m.symmetry_order)
    rel = 1.0 - res.rmse_m / rmse_max
    f_t = 0.0
    if p["score"] == "rmse":
        score = rel
    elif p["score"] == "fitness_rmse":
        score = res.fitness * rel
    else:
        f_t = tight_fitness(tpl, cKDTree(window), res, p["score_corr_m"])
        score = f_t
    h = Hypothesis(cls=cls, R=res.R, t=res.t, box=box, rmse_m=res.rmse_m, fitness=res.fitness,
                   f_t=f_t, score=float(score))
    h.accepted = True
    return h


def _class_hypotheses(cls: str, m, pts: np.ndarray, tree: cKDTree, lo, hi, p: dict, rankings: list,
                      stats: list) -> list:
    """Accepted fits of one class over its sliding windows (module doc, steps 2 to 4), one list per
    ranking (settings of `rankings`, equal to `p` apart from RANKING_KEYS): the windows are registered
    once (counted and timed in stats[0]), then accepted and scored for each ranking (timed in its own
    stats)."""
    t = time.perf_counter()
    wins, side = _class_windows(pts, lo, hi, m, p, stats[0])
    # The template loses what the seabed removal takes from a scan: its points this low above its base.
    templates = [IcpPoints.of(thin(v[v[:, 2] > p["ground_min_height_m"]], p["template_voxel_m"]),
                              p["icp_min_points_n"])
                 for v in paper_template(m, p["template_view"])]
    rmse_max = [per_class(r["rmse_max_m"], cls) for r in rankings]
    stats[0]["seconds"]["proposals"] += time.perf_counter() - t
    out = [[] for _ in rankings]
    # Windows holding exactly the points of an earlier window (sparse areas, overlapping windows) get
    # its fit: the same input gives the same ICP result, so only the cost changes (`windows_reused`).
    fits: dict[bytes, tuple | None] = {}
    for w in wins:
        t = time.perf_counter()
        centre = 0.5 * (w[:2] + w[2:])
        idx = np.asarray(tree.query_ball_point(centre, 0.5 * side, p=np.inf), dtype=np.int64)
        idx.sort()
        window = pts[idx]
        key = idx.tobytes() if p["reuse_identical_windows"] else None
        if key is not None and key in fits:
            best = fits[key]
            stats[0]["windows_reused"] += 1
        else:
            best = _best_fit(templates, window, p, stats[0])
            if key is not None:
                fits[key] = best
        stats[0]["seconds"]["registration"] += time.perf_counter() - t
        if best is None:
            continue
        for k, r in enumerate(rankings):
            if not (0 < best[0].rmse_m <= rmse_max[k]) or best[0].fitness < r["fitness_min"]:
                continue
            t = time.perf_counter()
            out[k].append(_hypothesis(cls, m, best[0], best[1], window, rmse_max[k], r))
            stats[k]["seconds"]["scoring"] += time.perf_counter() - t
    return out


def check_rankings(p: dict, rankings: list) -> None:
    """Raise ValueError unless every setting of `rankings` has a known score and equals `p` outside
    RANKING_KEYS (only then do they share the registrations)."""
    for r in rankings:
        if r["score"] not in SCORES:
            raise ValueError(f"paper parameter 'score' must be one of {SCORES}, got {r['score']!r}")
        differ = sorted(k for k in set(p) | set(r) if k not in RANKING_KEYS and p.get(k) != r.get(k))
        if differ:
            raise ValueError(f"paper settings that share a run may differ only in {RANKING_KEYS}; these differ too: "
                             f"{differ}")


def detect_paper_rankings(xyz: np.ndarray, models: dict, rankings: list, stats: list) -> list:
    """Run the paper pipeline on local-frame points (N,3, m) with the class models (class -> ClassModel)
    for one or more settings that differ only in RANKING_KEYS (`check_rankings`), sharing one seabed,
    one set of windows and one registration of each. Returns, per setting, the scored Hypothesis
    objects that survive its duplicate removal, best first (the same as a run of that setting
    alone), and adds its counts and per-stage seconds to the stats dict of the same index (the
    shared stages' counts and seconds in each; scoring and selection its own). Raises ValueError
    for settings that differ elsewhere or an unknown score."""
    if not rankings or len(rankings) != len(stats):
        raise ValueError(f"detect_paper_rankings needs one stats dict per setting ({len(rankings)} settings, "
                         f"{len(stats)} stats)")
    p = rankings[0]
    check_rankings(p, rankings)
    t = time.perf_counter()
    hab = seabed(xyz, p).hab
    pts = xyz[hab > p["ground_min_height_m"]]
    stats[0]["n_candidate_points"] = int(len(pts))
    stats[0]["capped"] = {"windows": 0}
    stats[0]["seconds"]["ground"] += time.perf_counter() - t
    log.info("seabed: %d points, %d candidates above it, %.1f s", len(xyz), len(pts), time.perf_counter() - t)
    dets = [[] for _ in rankings]
    if len(pts) >= MIN_RIGID_POINTS:
        tree = cKDTree(pts[:, :2])
        lo, hi = xyz[:, :2].min(0), xyz[:, :2].max(0)
        for cls, m in models.items():
            for k, hyps in enumerate(_class_hypotheses(cls, m, pts, tree, lo, hi, p, rankings, stats)):
                dets[k] += hyps
    for s in stats[1:]:
        for key in _SHARED_COUNTS:
            s[key] = stats[0][key] if key != "capped" else dict(stats[0][key])
        for stage in _SHARED_STAGES:
            s["seconds"][stage] += stats[0]["seconds"][stage]
    radius_m = {cls: m.radius_m for cls, m in models.items()}
    out = []
    for r, hyps, s in zip(rankings, dets, stats):
        s["hypotheses"] += len(hyps)
        t = time.perf_counter()
        hyps.sort(key=lambda h: -h.score)
        kept = []
        for h in hyps:
            if not is_duplicate(h, kept, radius_m, r):
                kept.append(h)
        s["seconds"]["selection"] += time.perf_counter() - t
        out.append(kept)
    return out
