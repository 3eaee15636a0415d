"""Variant `ours`: terrain-following seabed, BEV proposals, robust ICP, two-way scores, explain-away.

Steps (local scene frame, metres):
1. seabed: grid DTM (`ground.grid_ground`); points higher than `ground_min_height_m` are candidates;
2. proposals: per class, masked NCC of the height-above-seabed map with the class's top-surface
   kernels (yaw-sampled for tetrapods); peaks are proposals (class, x, y, yaw): compute goes only where
   the map holds something shaped like an object, never to empty seabed;
3. registration: per proposal, the candidate points around it (class radius + margin) are registered
   onto the class's mesh surface (`registration.icp_scene_to_model`), from the seabed height and, if
   the crop is taller than the class, from the top-aligned height; tetrapods from `n_yaw_init` yaws;
   rings and cones need no yaw search (continuous symmetry);
   Multi-start: the coarse ICP stage runs from every start; classes compete on its quality (share of
   crop points on the surface) and only the survivors get shifted restarts (escaping local minima of
   partly seen objects) and the fine stage;
4. scoring (`scoring`): f_t * f_s * RMSE term; plausibility: not sunk into the seabed;
5. selection: greedy explain-away: the best hypothesis is accepted, its inlier points are explained,
   hypotheses that shared those points are refitted on the unexplained points and re-scored, repeat;
   a much better hypothesis may replace weaker accepted ones whose points it explains;
6. re-proposal: the next round proposes only from unexplained points (explained cells count as
   unknown, not as empty, so a ring half-covered by an accepted ring still correlates), and tries
   tumbled orientations (resting poses of the mesh: cone on its side, ring on edge/upside down,
   tilted tetrapods) on unexplained clusters;
7. output: accepted objects with their score; other hypotheses that do not duplicate an accepted
   object keep a down-weighted score (more recall at low rank costs nothing in AP).
"""

from __future__ import annotations

import hashlib
import time

import numpy as np
import trimesh
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from ...geometry import points_in_box
from .ground import seabed
from .params import per_class
from .proposals import class_kernels, clusters, height_raster, ncc_maps, ncc_peaks, vote_map
from .registration import SceneSource, SurfaceTarget, icp_scene_to_model
from .scoring import Hypothesis, new_fraction, rescore, score_hypothesis


def rot_z(a: float) -> np.ndarray:
    """Rotation (3,3) by `a` rad about +z."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rot_x(a: float) -> np.ndarray:
    """Rotation (3,3) by `a` rad about +x."""
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


_TUMBLE_CACHE: dict = {}

#: Set to a list to record (event, round, details) tuples while debugging; None in normal use.
TRACE = None


def tumbled_rotations(model, n_azimuth: int = 8) -> list:
    """Rotations (3,3) of tumbled resting poses to try on unexplained clusters.

    Rings and cones: the mesh's distinct stable resting tilts other than upright (trimesh
    `compute_stable_poses`, tilts rounded to 5 deg; e.g. a cone on its side, a ring on edge or upside
    down), each at `n_azimuth` azimuths. Tetrapods rest on three legs in every stable pose (tetrahedral
    symmetry), so they get tilts of 30 and 55 deg (seen in piles) at 6 azimuths x 2 yaws, plus two
    upright yaws (a tetrapod resting on others may still be nearly upright). Upside-down
    poses (tilt > 150 deg) are left out: rings and cones fit them from the upright start (a ring is
    nearly mirror-symmetric; an upside-down cone is rare).
    """
    key = (model.cls, hashlib.sha1(np.ascontiguousarray(model.vertices).tobytes()).hexdigest(), n_azimuth)
    if key in _TUMBLE_CACHE:
        return _TUMBLE_CACHE[key]
    out = []
    if model.cls.startswith("tetrapod"):
        out += [rot_z(0.0), rot_z(np.pi / 3)]  # upright, as a start among the tilted ones
        for tilt in np.deg2rad([30.0, 55.0]):
            for az in np.arange(6) * np.pi / 3:
                for yaw in (0.0, np.pi / 3):
                    out.append(rot_z(az) @ rot_x(tilt) @ rot_z(yaw))
    else:
        mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
        with np.errstate(all="ignore"):
            transforms, probs = trimesh.poses.compute_stable_poses(mesh, n_samples=1, threshold=0.0)
        tilts = set()
        for T, p in zip(transforms, probs):
            tilt = float(np.degrees(np.arccos(np.clip(T[2, 2], -1, 1))))
            if not 60.0 <= tilt <= 150.0 or p < 1e-3:
                continue
            tilts.add(5.0 * round(tilt / 5.0))
        for tilt in sorted(tilts):
            for az in np.arange(n_azimuth) * 2 * np.pi / n_azimuth:
                out.append(rot_z(az) @ rot_x(np.deg2rad(tilt)))
    _TUMBLE_CACHE[key] = out
    return out


class _State:
    """Shared arrays of one detection run."""

    def __init__(self, xyz, ground, p):
        self.xyz = xyz
        self.ground = ground
        mask = ground.hab > p["ground_min_height_m"]
        self.pts = xyz[mask]
        self.hab = ground.hab[mask]
        self.seabed_xy = xyz[~mask, :2]
        self.active = np.ones(len(self.pts), dtype=bool)
        self.tree_xy = cKDTree(self.pts[:, :2]) if len(self.pts) else None
        self.all_tree_xy = cKDTree(xyz[:, :2])
        c = p["bev_cell_m"]
        # Cell-aligned raster origin: a crop of the survey (a tile) sees the same cells as the whole.
        self.x0, self.y0 = (float(np.floor(xyz[:, k].min() / c) * c) for k in (0, 1))
        self.shape = (int((xyz[:, 1].max() - self.y0) / c) + 1, int((xyz[:, 0].max() - self.x0) / c) + 1)
        self.rejected = []  # hypotheses not accepted (kept, down-weighted, for recall)
        self.owner = np.full(len(self.pts), -1, dtype=np.int64)  # uid of the accepted object explaining a point
        self.next_uid = 0
        self.tried = []  # (cls, xy, crop size) of upright proposals already fitted
        self.tried_tumbled = []  # the same for tumbled seeds


def _crop(st: _State, xy, radius: float, only_active: bool = True) -> np.ndarray:
    idx = np.asarray(st.tree_xy.query_ball_point(xy, radius), dtype=np.int64)
    idx.sort()
    if only_active and len(idx):
        idx = idx[st.active[idx]]
    return idx


class _Job:
    """The fitting state of one proposal: crop, ICP source, starts tried and the best coarse result."""

    def __init__(self, st, model, target, crop_idx, p, kind, occluders=(), xy=None):
        self.model, self.target, self.crop, self.kind = model, target, crop_idx, kind
        self.occluders, self.xy = occluders, xy
        P = st.pts[crop_idx]
        self.src = SceneSource(P, p["icp_min_points_n"])
        self.probe = P[:: max(1, len(P) // 150)]
        self.best, self.best_q = None, -1.0
        self.scale = len(P) / max(len(self.probe), 1)

    @property
    def best_n(self) -> float:
        """Estimated number of crop points within coarse_q_dist_m of the best coarse fit."""
        return max(self.best_q, 0.0) * len(self.crop)

    def passes(self, p) -> bool:
        """Worth finishing: coarse quality at least coarse_q_min, or (crowded crops, piles) enough crop
        points on the surface in absolute terms (coarse_n_min_frac x the class's median view size)."""
        if self.best is None:
            return False
        return self.best_q >= p["coarse_q_min"] or self.best_n >= p["coarse_n_min_frac"] * self.model.median_view_n

    def coarse(self, starts, p, stats, screen_keep: int = 0):
        """Coarse ICP stage from each start (R0, t0); keeps the best by the probe quality q (share of
        thinned crop points within coarse_q_dist_m of the posed surface). With screen_keep > 0 the
        starts are first screened by the cheaper `icp_screen_stage` and only the best screen_keep go on
        (many orientation starts, e.g. tumbled poses)."""
        if self.src.reason is not None:
            return
        if screen_keep > 0 and len(starts) > screen_keep:
            t = time.perf_counter()
            scr = [tuple(p["icp_screen_stage"])]
            ranked = []
            for k, (R0, t0) in enumerate(starts):
                stats["icp_runs"] += 1
                stats["icp_runs_by_kind"]["screen"] = stats["icp_runs_by_kind"].get("screen", 0) + 1
                res = icp_scene_to_model(self.src, self.target[0], R0, t0, scr, p["icp_tukey_k_frac"],
                                         p["icp_min_points_n"])
                if res is None:
                    continue
                q = float((self.model.distance((self.probe - res.t) @ res.R) < p["coarse_q_dist_m"]).mean())
                ranked.append((-q, k, (res.R, res.t)))
            ranked.sort(key=lambda r: (r[0], r[1]))
            starts = [r[2] for r in ranked[:screen_keep]]
            stats["seconds"]["registration"] += time.perf_counter() - t
        t = time.perf_counter()
        stage = [tuple(p["icp_stages"][0])]
        for R0, t0 in starts:
            stats["icp_runs"] += 1
            stats["icp_runs_by_kind"][self.kind] = stats["icp_runs_by_kind"].get(self.kind, 0) + 1
            res = icp_scene_to_model(self.src, self.target[0], R0, t0, stage, p["icp_tukey_k_frac"],
                                     p["icp_min_points_n"])
            if res is None:
                stats["icp_declined"] += 1
                continue
            q = float((self.model.distance((self.probe - res.t) @ res.R) < p["coarse_q_dist_m"]).mean())
            if TRACE is not None:
                TRACE.append(("q", self.kind, self.model.cls, tuple(np.asarray(t0)[:2]), q, tuple(res.t)))
            if q > self.best_q:
                self.best, self.best_q = res, q
        stats["seconds"]["registration"] += time.perf_counter() - t

    def shift(self, p, stats, q_min: float | None = None):
        """Coarse restarts `icp_xy_starts_m` off the best start in +-x, +-y, when its quality is in
        `icp_shift_q_range` (not hopeless, not already converged): escapes local minima of partly
        seen objects (a cone seen from one side slides to a wrong fit 0.15 m off)."""
        d = float(p["icp_xy_starts_m"])
        lo, hi = p["icp_shift_q_range"]
        lo = lo if q_min is None else q_min
        if self.best is None or d <= 0 or not lo <= self.best_q < hi:
            return
        R0, t0 = self.best.R, self.best.t
        self.coarse([(R0, t0 + [c * d, s_ * d, 0.0]) for c, s_ in ((1, 0), (0, 1), (-1, 0), (0, -1))], p, stats)

    def finish(self, st, p, stats):
        """Fine ICP stages from the best coarse result, then scoring; None if ICP declines."""
        if self.best is None:
            return None
        t = time.perf_counter()
        stages = [tuple(x) for x in p["icp_stages"]]
        res = self.best
        if len(stages) > 1:
            res = icp_scene_to_model(self.src, self.target[1], res.R, res.t, stages[1:], p["icp_tukey_k_frac"],
                                     p["icp_min_points_n"])
        stats["seconds"]["registration"] += time.perf_counter() - t
        if res is None:
            return None
        return _score(st, self.model, res, p, stats, self.occluders)


def _score(st, model, res, p, stats, occluders):
    t = time.perf_counter()
    h = score_hypothesis(model, res.R, res.t, model.cls, st.pts, st.active, st.tree_xy, st.xyz,
                         st.all_tree_xy, p, per_class(p["rmse_max_m"], model.cls), occluders)
    h.fitness = res.fitness
    # Plausibility: the object cannot be sunk into the seabed.
    v = model.vertices[::7] @ res.R.T + res.t
    low = v[np.argmin(v[:, 2])]
    if low[2] < float(st.ground.z_at(low[0], low[1])) - p["sink_max_m"]:
        h.score = 0.0
        h.f_s = 0.0
    stats["seconds"]["scoring"] += time.perf_counter() - t
    return h


def _fit(st, model, target, R0, t0, crop_idx, p, stats, occluders=(), kind="refit"):
    """ICP of the crop onto the model from (R0, t0) (all stages, one start), then scoring; None if ICP declines."""
    job = _Job(st, model, target, crop_idx, p, kind, occluders)
    job.coarse([(R0, t0)], p, stats)
    return job.finish(st, p, stats)


def _z_inits(st, model, xy, crop_idx):
    zg = float(st.ground.z_at(xy[0], xy[1]))
    out = [zg]
    if len(crop_idx):
        ztop = float(st.pts[crop_idx, 2].max()) - model.height_m
        if ztop > zg + 0.25:
            out.append(ztop)
    return out


def _propose_upright(st, models, kernels, p, rnd, accepted, stats):
    """Round proposals: NCC peaks per class on the map of unexplained points (explained cells unknown)."""
    t = time.perf_counter()
    act = st.active
    xy = np.concatenate([st.seabed_xy, st.pts[act, :2]])
    hv = np.concatenate([np.zeros(len(st.seabed_xy)), st.hab[act]])
    r = height_raster(xy, hv, p["bev_cell_m"], st.x0, st.y0, st.shape)
    if (~act).any():
        # Cells only explained objects occupy: unknown (an accepted object may hide what is below it).
        ex = height_raster(st.pts[~act, :2], st.hab[~act], p["bev_cell_m"], st.x0, st.y0, st.shape)
        hidden = np.isfinite(ex.h) & ~(r.h > p["ground_min_height_m"])
        r.h[hidden] = np.nan
    out = []
    for cls, m in models.items():
        best, arg, occ = ncc_maps(r, kernels[cls], p["ground_min_height_m"])
        if TRACE is not None:
            TRACE.append(("raster", rnd, cls, (np.inf, np.inf), r.h.copy(), best, occ))
        rad = int(round(p["proposal_nms_radius_frac"] * m.radius_m / p["bev_cell_m"]))
        ii, jj = ncc_peaks(best, occ, p["proposal_ncc_min"], p["proposal_occupancy_min_frac"], rad)
        yaw_of = [kernels[cls][arg[i, j]].yaw_rad for i, j in zip(ii, jj)]
        if rnd > 0:
            # Partly hidden objects: plain occupancy votes of the unexplained points.
            vb, va = vote_map(r, kernels[cls], p["ground_min_height_m"])
            vi, vj = ncc_peaks(vb, np.ones_like(vb), p["proposal_vote_min_frac"], 0.0, rad)
            ii, jj = np.r_[ii, vi], np.r_[jj, vj]
            yaw_of += [kernels[cls][va[i, j]].yaw_rad for i, j in zip(vi, vj)]
        centres = r.centre(ii, jj)
        kept = []
        for (x, y), i, j, yaw in zip(centres, ii, jj, yaw_of):
            if any(np.hypot(x - kx, y - ky) < p["proposal_merge_m"] for kx, ky in kept):
                continue
            if any(a.cls == cls and np.hypot(*(a.t[:2] - [x, y])) < 0.5 * m.radius_m for a in accepted):
                continue
            kept.append((x, y))
            out.append((cls, np.array([x, y]), yaw, float(best[i, j])))
            if TRACE is not None:
                TRACE.append(("proposal", rnd, cls, (x, y), float(best[i, j])))
    stats["seconds"]["proposals"] += time.perf_counter() - t
    return out


def _near_boxes(accepted, xy, radius):
    return [a.box for a in accepted if np.hypot(*(a.box[:2] - xy)) < radius + 0.5 * np.hypot(a.box[3], a.box[4])]


def _screened_crop(st, cls, m, xy, p, stats, tried: list):
    """The candidate points around a proposal of class `cls` at `xy`, or None (counted in `stats`)
    when they are too few or too low for the class, or when the same class was already tried there on
    the very same points (an earlier round would give the same fit). Records the try in `tried`."""
    stats["windows"] += 1
    crop = _crop(st, xy, m.radius_m + p["crop_margin_m"])
    if len(crop) < max(p["icp_min_points_n"], p["proposal_min_points_frac"] * m.median_view_n) \
            or st.hab[crop].max() < p["proposal_min_height_frac"] * m.height_m:
        stats["windows_skipped"] += 1
        return None
    if any(c == cls and n == len(crop) and np.hypot(*(xy - q)) < p["proposal_merge_m"] for c, q, n in tried):
        stats["proposals_repeated"] += 1
        return None
    tried.append((cls, xy, len(crop)))
    return crop


def _hypotheses_upright(st, models, targets, proposals, p, rnd, accepted, stats):
    """Upright hypotheses: coarse ICP of every proposal from its starts (seabed/top-aligned heights x
    yaws), class competition among nearby proposals on the coarse quality, shifted restarts and fine
    ICP + scoring for the survivors."""
    jobs = []
    for cls, xy, yaw, _ in proposals:
        m = models[cls]
        crop = _screened_crop(st, cls, m, xy, p, stats, st.tried)
        if crop is None:
            continue
        n_yaw = 1 if m.symmetric else max(1, int(p["n_yaw_init"]))
        yaws = [yaw + k * m.yaw_period_rad / n_yaw for k in range(n_yaw)]
        job = _Job(st, m, targets[cls], crop, p, f"upright{rnd}", _near_boxes(accepted, xy, m.radius_m + 0.5), xy)
        job.coarse([(rot_z(yw), np.r_[xy, z0]) for z0 in _z_inits(st, m, xy, crop) for yw in yaws], p, stats)
        if job.best is not None:
            jobs.append(job)
    # Class competition: near one another, proposals far below the best coarse quality are dropped.
    qs = np.array([j.best_q for j in jobs])
    xys = np.array([j.xy for j in jobs]).reshape(-1, 2)
    hyps = []
    for k, job in enumerate(jobs):
        near = np.hypot(*(xys - job.xy).T) < p["class_competition_m"]
        if not job.passes(p) or job.best_q < qs[near].max() - p["class_q_margin"]:
            stats["proposals_outcompeted"] += 1
            continue
        job.shift(p, stats)
        h = job.finish(st, p, stats)
        if h is not None:
            h.round, h.seed_xy = rnd, job.xy
            hyps.append(h)
    return hyps


def _residual_seeds(st, g_idx, p) -> list:
    """Seed positions (x, y) in one cluster of unexplained points: the peaks of the smoothed point
    density (Gaussian `residual_seed_sigma_m`, peaks at least `residual_seed_sep_m` apart), which sit
    near the middle of each object's visible part even when objects touch or pile up; plus the
    cluster's centroid unless a peak is that close."""
    cell = 0.1
    xy = st.pts[g_idx, :2]
    lo = np.floor((xy.min(0) - 1.0) / cell) * cell  # cell-aligned: a crop sees the same cells
    shape = tuple((np.ceil((xy.max(0) + 1.0 - lo) / cell)).astype(int)[::-1])
    j = ((xy[:, 0] - lo[0]) / cell).astype(int)
    i = ((xy[:, 1] - lo[1]) / cell).astype(int)
    dens = np.zeros(shape)
    np.add.at(dens, (i, j), 1.0)
    dens = ndi.gaussian_filter(dens, p["residual_seed_sigma_m"] / cell, mode="constant")
    size = 2 * int(round(p["residual_seed_sep_m"] / cell)) + 1
    peak = (dens >= ndi.maximum_filter(dens, size=size, mode="constant")) & (dens >= 0.25 * dens.max())
    pi, pj = np.nonzero(peak)
    order = np.argsort(-dens[pi, pj], kind="stable")[: int(p["residual_max_seeds_n"])]
    seeds = [np.array([lo[0] + (pj[k] + 0.5) * cell, lo[1] + (pi[k] + 0.5) * cell]) for k in order]
    c = xy.mean(0)
    if all(np.hypot(*(c - q)) > 0.3 for q in seeds):
        seeds.append(c)
    return seeds


def _hypotheses_tumbled(st, models, targets, p, rnd, accepted, stats):
    """Tumbled-orientation hypotheses on clusters of unexplained points (seeds: `_residual_seeds`)."""
    # Leftovers of accepted objects (points just beyond claim_m of their mesh: feet, edges, noise) are
    # not new objects: points within 2 x claim_m of an accepted mesh do not seed.
    free = st.active.copy()
    for a in accepted:
        m = models[a.cls]
        idx = _crop(st, a.t[:2], m.radius_m + 0.3)
        if len(idx):
            idx = idx[points_in_box(st.pts[idx], a.box, 0.3)]
            free[idx[m.distance((st.pts[idx] - a.t) @ a.R) < 2 * p["claim_m"]]] = False
    idx_act = np.flatnonzero(free)
    if len(idx_act) == 0:
        return []
    hyps = []
    for grp in clusters(st.pts[idx_act, :2], 0.2, p["residual_min_points_n"]):
        g = idx_act[grp]
        top = float(st.hab[g].max())
        if top < p["residual_min_height_m"]:
            continue
        for xy in _residual_seeds(st, g, p):
            for cls, m in models.items():
                rots = tumbled_rotations(m)
                if not rots:
                    continue
                crop = _screened_crop(st, cls, m, xy, p, stats, st.tried_tumbled)
                if crop is None:
                    continue
                zg = float(st.ground.z_at(xy[0], xy[1]))
                ztop = float(st.pts[crop, 2].max())
                crop_h = float(st.hab[crop].max())
                starts = []
                for R0 in rots:
                    v = m.vertices[::5] @ R0.T
                    if crop_h < p["proposal_min_height_frac"] * (v[:, 2].max() - v[:, 2].min()):
                        continue  # the crop is too low for the object in this pose
                    c = 0.5 * (v.min(0) + v.max(0))
                    base = np.array([xy[0] - c[0], xy[1] - c[1], zg - v[:, 2].min()])
                    starts.append((R0, base))
                    lift = ztop - v[:, 2].max() - base[2]
                    if lift > 0.25:  # the crop is taller than this pose: maybe resting on others
                        starts.append((R0, base + [0.0, 0.0, lift]))
                if not starts:
                    stats["windows_skipped"] += 1
                    continue
                job = _Job(st, m, targets[cls], crop, p, "tumbled", _near_boxes(accepted, xy, m.radius_m + 0.5), xy)
                job.coarse(starts, p, stats, screen_keep=int(p["tumbled_screen_keep_n"]))
                if not job.passes(p):
                    continue
                job.shift(p, stats, p["tumbled_shift_q_min"])
                h = job.finish(st, p, stats)
                if h is not None:
                    h.round, h.seed_xy = rnd, xy
                    hyps.append(h)
    return hyps


def _penetration(h, a, models) -> float:
    """Share of h's surface samples (every 3rd) inside accepted object a's mesh."""
    if np.hypot(*(h.t[:2] - a.t[:2])) > models[h.cls].radius_m + models[a.cls].radius_m:
        return 0.0
    s = models[h.cls].surface[::3] @ h.R.T + h.t
    return float(models[a.cls].inside((s - a.t) @ a.R).mean())


def _claim(st, h, models, p):
    """Indices of candidate points the accepted hypothesis explains (within claim_m of its mesh)."""
    m = models[h.cls]
    idx = _crop(st, h.t[:2], m.radius_m + 0.2, only_active=True)
    if len(idx) == 0:
        return idx
    d = m.distance((st.pts[idx] - h.t) @ h.R)
    return idx[d < p["claim_m"]]


def _own(st, h, models, p):
    """Mark the points an accepted hypothesis explains (inliers + claimed) as owned by it."""
    claimed = _claim(st, h, models, p)
    idx = np.union1d(claimed, h.cand[h.inl][st.active[h.cand[h.inl]]])
    st.active[idx] = False
    st.owner[idx] = h.uid
    return idx


def _disown(st, a):
    """Give back the points accepted hypothesis a owned (it is being replaced)."""
    idx = np.flatnonzero(st.owner == a.uid)
    st.active[idx] = True
    st.owner[idx] = -1


def _replaceable(st, h, accepted, p):
    """Accepted objects h may replace: those owning at least 20 % of h's inliers, if h scores at least
    `replace_factor` times each of them (a tumbled big tetrapod over a small one accepted first)."""
    inl = h.cand[h.inl]
    if len(inl) == 0:
        return []
    owners = st.owner[inl]
    ids, counts = np.unique(owners[owners >= 0], return_counts=True)
    conf = [a for a in accepted if a.uid in set(ids[counts >= 0.2 * len(inl)].tolist())]
    if conf and all(h.score >= p["replace_factor"] * a.score for a in conf):
        return conf
    return []


def _select(st, models, targets, pending, accepted, p, stats):
    """Greedy explain-away over pending hypotheses; returns the newly accepted ones.

    The best pending hypothesis is accepted when its score reaches `accept_min`, at least
    `new_min_frac` of its inliers are still unexplained (else it may replace weaker accepted objects
    owning them, see `_replaceable`), its RMSE is within the class limit and it does not interpenetrate
    an accepted object. Its points are then explained; pending hypotheses that shared them are refitted
    on the remaining points (up to twice) or re-scored.
    """
    t = time.perf_counter()
    new_acc = []
    rmse_max = {c: per_class(p["rmse_max_m"], c) for c in models}
    while pending:
        k = int(np.argmax([h.score for h in pending]))
        h = pending[k]
        if h.score < p["accept_min"]:
            break
        pending.pop(k)
        replace = []
        new_ok = new_fraction(h, st.active) >= p["new_min_frac"]
        if not new_ok and p["replace_factor"] > 0:
            replace = _replaceable(st, h, accepted, p)
        others = [a for a in accepted if all(a is not r for r in replace)]
        ok = ((new_ok or bool(replace)) and h.rmse_m <= rmse_max[h.cls]
              and all(_penetration(h, a, models) <= p["penetration_max_frac"]
                      and _penetration(a, h, models) <= p["penetration_max_frac"] for a in others))
        if TRACE is not None:
            TRACE.append(("decide", h.round, h.cls, tuple(h.box[:2]), h.score, ok, new_fraction(h, st.active),
                          h.f_t, h.f_s, h.rmse_m, len(replace)))
        if not ok:
            h.score = 0.0 if not new_ok and not replace else h.score
            st.rejected.append(h)
            continue
        gone = np.zeros(len(st.active), dtype=bool)
        changed = np.zeros(len(st.active), dtype=bool)
        for a in replace:
            changed |= st.owner == a.uid
            _disown(st, a)
            accepted[:] = [b for b in accepted if b is not a]
            new_acc[:] = [b for b in new_acc if b is not a]
            st.rejected.append(a)
            stats["replaced"] += 1
        h.uid = st.next_uid
        st.next_uid += 1
        accepted.append(h)
        new_acc.append(h)
        idx = _own(st, h, models, p)
        gone[idx] = True
        changed[idx] = True
        # Hypotheses that shared the explained points: refit on what is left, then re-score.
        for j, o in enumerate(pending):
            if len(o.cand) == 0:
                continue
            if not changed[o.cand].any():
                continue
            lost = gone[o.cand].mean()
            if lost > 0.1 and o.n_refits < 2:
                m = models[o.cls]
                crop = _crop(st, o.t[:2], m.radius_m + p["crop_margin_m"])
                ref = _fit(st, m, targets[o.cls], o.R, o.t, crop, p, stats,
                           _near_boxes(accepted, o.t[:2], m.radius_m + 0.5), kind="refit") \
                    if len(crop) >= p["icp_min_points_n"] else None
                if ref is not None:
                    ref.round, ref.seed_xy, ref.n_refits = o.round, o.seed_xy, o.n_refits + 1
                    pending[j] = ref
                    stats["refits"] += 1
                    continue
            rescore(o, st.active, rmse_max[o.cls])
    st.rejected.extend(pending)
    stats["seconds"]["selection"] += time.perf_counter() - t
    return new_acc


def detect_ours(xyz: np.ndarray, models: dict, p: dict, stats: dict) -> list:
    """Run the `ours` pipeline on local-frame points (N,3); returns scored Hypothesis objects
    (accepted ones first, then down-weighted others) with `accepted` set on each."""
    t = time.perf_counter()
    ground = seabed(xyz, p)
    st = _State(xyz, ground, p)
    stats["replaced"] = 0
    stats["proposals_repeated"] = 0
    stats["proposals_outcompeted"] = 0
    stats["n_candidate_points"] = int(len(st.pts))
    stats["seconds"]["ground"] += time.perf_counter() - t
    if len(st.pts) < p["icp_min_points_n"]:
        return []
    t = time.perf_counter()
    targets = {c: (SurfaceTarget(m.coarse_surface, m.coarse_normals), SurfaceTarget(m.surface, m.surface_normals))
               for c, m in models.items()}
    kernels = {c: class_kernels(m, p["bev_cell_m"], p["bev_yaw_step_deg"]) for c, m in models.items()}
    stats["seconds"]["models"] += time.perf_counter() - t
    accepted: list[Hypothesis] = []
    for rnd in range(int(p["proposal_max_rounds_n"])):
        props = _propose_upright(st, models, kernels, p, rnd, accepted, stats)
        pending = _hypotheses_upright(st, models, targets, props, p, rnd, accepted, stats)
        if rnd > 0 and p["tumbled_inits"]:
            pending += _hypotheses_tumbled(st, models, targets, p, rnd, accepted, stats)
        stats["hypotheses"] += len(pending)
        new = _select(st, models, targets, pending, accepted, p, stats)
        stats["accepted_per_round"].append(len(new))
        if not new and rnd > 0:
            break
    for h in accepted:
        h.accepted = True
    out = list(accepted)
    if p["keep_rejected"]:
        rest = sorted((h for h in st.rejected if h.score >= p["score_min"]), key=lambda h: -h.score)
        kept = []
        for h in rest:
            if any(np.hypot(*(h.box[:2] - a.box[:2])) < p["duplicate_dist_m"] for a in accepted + kept):
                continue
            h.accepted = False
            h.score *= p["rejected_score_factor"]
            kept.append(h)
        out += kept
    return out
