"""Variant `paper`: the source study's pipeline, reconstructed.

1. seabed: one RANSAC plane (Open3D `segment_plane` on a seeded random subset of `ransac_sample_n`
   points); points more than `ground_min_height_m` above it are object candidates;
2. segmentation: per class, square sliding windows of side = class footprint x `window_scale` with
   `window_overlap`; windows holding fewer candidate points than `window_min_points_frac` x the
   class's median template-view size are skipped (counted in the statistics); flat windows (thinner
   than `window_min_thickness_m`: seabed, a planar patch) are not registered (degenerate input);
3. registration: one template view per class (`template_view`: the nadir view at yaw 0), without its
   points lower than `ground_min_height_m` above its base (the seabed removal takes those from a
   scan too), moved onto the window's points by centroid alignment + point-to-point ICP;
4. acceptance: inlier RMSE <= `rmse_max_m[cls]` and fitness >= `fitness_min`; score =
   1 - rmse / rmse_max (`score` 'rmse': the RMSE relative to the class threshold ranks, as the study
   ranks by RMSE) or fitness * (1 - rmse / rmse_max) ('fitness_rmse');
5. duplicates: across classes, detections whose box centres are closer than `duplicate_dist_m` keep
   only the best score.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.spatial import cKDTree

from ...geometry import matrix_to_quat
from ...objects.catalog import canonical_box
from .ground import seabed
from .params import per_class
from .proposals import sliding_windows, window_counts
from .registration import icp_point_to_point
from .scoring import Hypothesis


def paper_template(model, which: str, tv_meta=None) -> list:
    """Template point sets (canonical) the paper variant registers: ['nadir'] one view, ['all'] every view."""
    if which == "all":
        return [v for v in model.views if len(v)]
    meta = model.view_meta
    order = sorted(range(len(model.views)), key=lambda k: (abs(meta["offset_m"][k]), abs(meta["yaw_rad"][k]), k))
    for k in order:
        if len(model.views[k]) >= 3:
            return [model.views[k]]
    raise ValueError(f"class {model.cls!r} has no template view with points")


def thin(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """One point (the first) per `voxel_m` voxel, order kept (deterministic)."""
    if voxel_m <= 0 or len(points) == 0:
        return points
    k = np.floor(points / voxel_m).astype(np.int64)
    _, first = np.unique(k, axis=0, return_index=True)
    return points[np.sort(first)]


def detect_paper(xyz: np.ndarray, models: dict, p: dict, stats: dict) -> list:
    """Run the paper pipeline on local-frame points (N,3); returns scored Hypothesis objects."""
    t = time.perf_counter()
    hab = seabed(xyz, p).hab
    pts = xyz[hab > p["ground_min_height_m"]]
    stats["n_candidate_points"] = int(len(pts))
    stats["seconds"]["ground"] += time.perf_counter() - t
    if len(pts) < 3:
        return []
    tree = cKDTree(pts[:, :2])
    lo, hi = xyz[:, :2].min(0), xyz[:, :2].max(0)
    dets = []
    for cls, m in models.items():
        t = time.perf_counter()
        side = m.footprint_m * p["window_scale"]
        wins = sliding_windows(lo, hi, side, p["window_overlap"])
        counts = window_counts(pts[:, :2], wins)
        n_min = p["window_min_points_frac"] * float(np.median([len(v) for v in m.views]))
        run = counts >= n_min if p["skip_empty_windows"] else np.ones(len(wins), dtype=bool)
        stats["windows"] += len(wins)
        stats["windows_skipped"] += int((~run).sum())
        # The template loses what the seabed removal takes from a scan: its points this low above its base.
        templates = [thin(v[v[:, 2] > p["ground_min_height_m"]], p["template_voxel_m"])
                     for v in paper_template(m, p["template_view"])]
        rmse_max = per_class(p["rmse_max_m"], cls)
        stats["seconds"]["proposals"] += time.perf_counter() - t
        for w in wins[run]:
            t = time.perf_counter()
            centre = 0.5 * (w[:2] + w[2:])
            idx = np.asarray(tree.query_ball_point(centre, 0.5 * side, p=np.inf), dtype=np.int64)
            idx.sort()
            window = pts[idx]
            best = None
            for tpl in templates:
                stats["icp_runs"] += 1
                res = icp_point_to_point(tpl, window, p["icp_max_corr_m"], p["icp_max_iter"],
                                         min_thickness_m=p["window_min_thickness_m"])
                if res is None:
                    stats["icp_declined"] += 1
                    continue
                if best is None or res.rmse_m < best.rmse_m:
                    best = res
            stats["seconds"]["registration"] += time.perf_counter() - t
            if best is None or not (0 < best.rmse_m <= rmse_max) or best.fitness < p["fitness_min"]:
                continue
            box = canonical_box(m.vertices, best.t, matrix_to_quat(best.R), m.symmetry_order)
            rel = 1.0 - best.rmse_m / rmse_max
            score = rel if p["score"] == "rmse" else best.fitness * rel
            h = Hypothesis(cls=cls, R=best.R, t=best.t, box=box, rmse_m=best.rmse_m, fitness=best.fitness,
                           score=float(score))
            h.accepted = True
            dets.append(h)
    stats["hypotheses"] += len(dets)
    t = time.perf_counter()
    dets.sort(key=lambda h: -h.score)
    kept = []
    for h in dets:
        if all(np.hypot(*(h.box[:2] - k.box[:2])) >= p["duplicate_dist_m"] for k in kept):
            kept.append(h)
    stats["seconds"]["selection"] += time.perf_counter() - t
    return kept
