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

Threads: within a round the fits of the proposals, the tumbled tries and the refits, and the
per-class correlations, depend only on the state at the round's start; they run on the detector
call's worker threads (`tasks`, `ModelBasedDetector(threads=N)`), in input order, so the detections
and counts are the same for any N.

Time bound: a round fits at most `proposal_max_per_round_n` upright proposals (the best-correlating)
and as many tumbled seed tries; on a dense or pathological cloud (noise everywhere above the seabed)
the rest are dropped, counted in stats["capped"] and logged (WARNING). Every stage logs its counts at
INFO level (logger ``sonardet.detect.model_based.ours``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy import ndimage as ndi
from scipy.spatial import cKDTree

from ...geometry import points_in_box
from .ground import seabed
from .grid_icp import NearestSurfaceGrid, icp_point_to_plane_starts
from .models import NEAR_SPACINGS, ClassModel, rot_x, rot_z
from .params import per_class
from .proposals import (
    Correlator,
    class_kernels,
    clusters,
    height_raster,
    ncc_maps,
    ncc_peaks,
    vote_map,
)
from .registration import IcpResult, SceneSource, SurfaceTarget, icp_scene_to_model, is_rigid_transform
from .scoring import (
    CoverageViews,
    Hypothesis,
    SceneIndex,
    new_fraction,
    rescore,
    score_hypothesis,
    shape_tolerance_m,
    support_neighbours,
    support_overhangs,
    tolerant_distance,
    view_points,
)
from .tasks import run_tasks

log = logging.getLogger(__name__)


def _given_tilts(tumble: dict) -> list:
    """Tumbled starts of a class whose stable poses are all upright (e.g. a tetrapod, which rests on
    three legs whatever the pose): its upright yaws (resting on others it may still be nearly
    upright), then each of its tilts at each azimuth and yaw (the class spec's `tumble`)."""
    yaws = np.deg2rad(tumble["yaws_deg"])
    n_az = int(tumble["azimuths_n"])
    out = [rot_z(yaw) for yaw in np.deg2rad(tumble["upright_yaws_deg"])]
    for tilt in np.deg2rad(tumble["tilts_deg"]):
        for az in np.arange(n_az) * 2 * np.pi / n_az:
            for yaw in yaws:
                out.append(rot_z(az) @ rot_x(tilt) @ rot_z(yaw))
    return out


def _stable_tilts_deg(model: ClassModel, p: dict) -> list[float]:
    """Distinct tilts (deg, rounded to `tumbled_tilt_round_deg`) of the mesh's stable resting poses
    (trimesh `compute_stable_poses`) within `tumbled_stable_tilt_range_deg` and at least
    `tumbled_stable_prob_min` probable, ascending."""
    mesh = trimesh.Trimesh(model.vertices, model.faces, process=False)
    with np.errstate(all="ignore"):
        transforms, probs = trimesh.poses.compute_stable_poses(mesh, n_samples=1, threshold=0.0)
    lo, hi = p["tumbled_stable_tilt_range_deg"]
    step = p["tumbled_tilt_round_deg"]
    tilts = set()
    for T, prob in zip(transforms, probs):
        tilt = float(np.degrees(np.arccos(np.clip(T[2, 2], -1, 1))))
        if not lo <= tilt <= hi or prob < p["tumbled_stable_prob_min"]:
            continue
        tilts.add(step * round(tilt / step))
    return sorted(tilts)


def tumbled_rotations(model: ClassModel, p: dict) -> list:
    """Rotations (3,3, canonical -> scene) of tumbled resting poses to try on unexplained clusters.

    What the class spec's `tumble` (model.tumble) says: mode 'stable_poses' (rings, cones): the mesh's
    distinct stable resting tilts other than upright (`_stable_tilts_deg`; e.g. a cone on its side, a
    ring on edge), each at `tumbled_azimuths_n` azimuths; upside-down poses are left out by the
    default tilt range (rings and cones fit them from the upright start: a ring is nearly
    mirror-symmetric, an upside-down cone is rare). Mode 'tilts' (tetrapods: every stable pose rests
    on three legs): the spec's tilts (seen in piles) at its azimuths and yaws, plus its upright yaws.
    """
    if model.tumble.get("mode") == "tilts":
        return _given_tilts(model.tumble)
    n_az = int(p["tumbled_azimuths_n"])
    out = []
    for tilt in _stable_tilts_deg(model, p):
        for az in np.arange(n_az) * 2 * np.pi / n_az:
            out.append(rot_z(az) @ rot_x(np.deg2rad(tilt)))
    return out


@dataclass
class OursClass:
    """What variant `ours` derives once from one class model and its parameters (canonical frame, m).

    model: the ClassModel; targets: (coarse, fine) ICP targets (the mesh surface sampled at two
    spacings); kernels: BEV kernels of the proposals (`proposals.class_kernels`); tumbled: rotations
    of the tumbled starts (`tumbled_rotations`; empty when `tumbled_inits` is off) and tumbled_extents
    their `pose_extents`; views: the
    template views thinned to `coverage_voxel_m` with their surface normals (`scoring.CoverageViews`;
    the template->scene fraction of upright poses); grids: the nearest-sample grids (`grid_icp`) of
    the coarse surface (screening and first ICP stage) and of the fine surface (later stages, coarse
    quality); None when `icp_grid_cell_m` is 0 (Open3D's ICP and SciPy's k-d tree then).
    """

    model: ClassModel
    targets: tuple[SurfaceTarget, SurfaceTarget]
    kernels: list
    tumbled: list
    views: CoverageViews
    grids: tuple[NearestSurfaceGrid, NearestSurfaceGrid] | None = None
    tumbled_extents: list | None = None


def prepare_classes(models: dict[str, ClassModel], p: dict) -> dict[str, OursClass]:
    """The per-class data of variant `ours` (class -> OursClass), built once per detector."""
    out = {}
    for cls, m in models.items():
        tumbled = tumbled_rotations(m, p) if p["tumbled_inits"] else []
        out[cls] = OursClass(
            model=m,
            targets=(SurfaceTarget(m.coarse_surface, m.coarse_normals), SurfaceTarget(m.surface, m.surface_normals)),
            kernels=class_kernels(m, p["bev_cell_m"], p["bev_yaw_step_deg"]),
            tumbled=tumbled,
            views=CoverageViews.of(m, view_points(m.views, p["coverage_voxel_m"])),
            grids=_surface_grids(m, p),
            tumbled_extents=pose_extents(m, tumbled, int(p["tumbled_vertex_stride_n"])))
    return out


def _surface_grids(m: ClassModel, p: dict):
    """Nearest-sample grids of the coarse surface (screening and first ICP stage) and of the fine
    surface (later stages, coarse quality), each reaching as far as the correspondence distances it
    serves; None when `icp_grid_cell_m` is 0."""
    cell = float(p["icp_grid_cell_m"])
    if cell <= 0:
        return None
    coarse = max(float(p["icp_screen_stage"][0]), float(p["icp_stages"][0][0]))
    fine = max([float(s[0]) for s in p["icp_stages"][1:]]
               + [float(p["coarse_q_dist_m"]), NEAR_SPACINGS * m.surface_spacing_m])
    return (NearestSurfaceGrid(m.coarse_surface, m.coarse_normals, cell, coarse),
            NearestSurfaceGrid(m.surface, m.surface_normals, cell, fine))


class _State:
    """Shared arrays of one detection run."""

    def __init__(self, xyz, ground, p, pool=None, all_tree_xy=None):
        self.xyz = xyz
        self.pool = pool  # worker threads of this run (`tasks.worker_pool`), None: all on the caller's
        self.ground = ground
        mask = ground.hab > p["ground_min_height_m"]
        self.pts = xyz[mask]
        self.hab = ground.hab[mask]
        self.seabed_xy = xyz[~mask, :2]
        self.active = np.ones(len(self.pts), dtype=bool)
        self.tree_xy = cKDTree(self.pts[:, :2]) if len(self.pts) else None
        self.scene = SceneIndex(self.pts, self.active, self.tree_xy, xyz,
                                cKDTree(xyz[:, :2]) if all_tree_xy is None else all_tree_xy)
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


def _count(stats: dict, kind: str) -> None:
    stats["icp_runs"] += 1
    stats["icp_runs_by_kind"][kind] = stats["icp_runs_by_kind"].get(kind, 0) + 1


class _Job:
    """The fitting state of one proposal: crop, ICP source, starts tried and the best coarse result."""

    def __init__(self, st, k: OursClass, crop_idx, p, kind, occluders=(), xy=None):
        self.k, self.model, self.target, self.crop, self.kind = k, k.model, k.targets, crop_idx, kind
        self.occluders, self.xy = occluders, xy
        P = st.pts[crop_idx]
        self.src = SceneSource(P, p["icp_min_points_n"])
        self.probe = P[:: max(1, len(P) // int(p["coarse_probe_points_n"]))]
        self.best, self.best_q = None, -1.0

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

    def _register(self, starts, stage, p, level: int = 0) -> list:
        """One ICP stage (max correspondence m, iterations, source voxel m) of the crop from each start
        (R0, t0) onto the coarse (level 0) or fine (1) surface: IcpResult or None (declined) per start.
        All starts in one compiled call on the class's nearest-sample grid (`grid_icp`) when it has
        one, else one Open3D call per start."""
        if self.k.grids is None:
            return [icp_scene_to_model(self.src, self.target[level], R0, t0, [stage], p["icp_tukey_k_frac"],
                                       p["icp_min_points_n"]) for R0, t0 in starts]
        if not starts:
            return []
        max_corr, n_iter, voxel = stage
        src = self.src.points_at(voxel)
        T0 = np.zeros((len(starts), 4, 4))
        for i, (R0, t0) in enumerate(starts):  # scene -> canonical is the inverse pose
            T0[i, :3, :3] = R0.T
            T0[i, :3, 3] = -R0.T @ t0
            T0[i, 3, 3] = 1.0
        exact = level > 0 or bool(p["icp_grid_exact_coarse"])
        T, fit, rmse, n_corr = icp_point_to_plane_starts(src, T0, self.k.grids[level], max_corr,
                                                         p["icp_tukey_k_frac"] * max_corr, n_iter, exact=exact)
        out = []
        for i in range(len(starts)):
            if n_corr[i] < p["icp_min_points_n"] or not is_rigid_transform(T[i]):
                out.append(None)
                continue
            R = T[i, :3, :3].T.copy()
            out.append(IcpResult(R, -R @ T[i, :3, 3], float(fit[i]), float(rmse[i])))
        return out

    def qualities(self, results, p) -> np.ndarray:
        """Coarse quality of each ICP result (-1 for None): the share of the probe points (thinned crop)
        within coarse_q_dist_m of the posed surface, for all results in one nearest-sample query."""
        q = np.full(len(results), -1.0)
        ok = [i for i, r in enumerate(results) if r is not None]
        if not ok:
            return q
        P = self.probe
        moved = np.concatenate([(P - results[i].t) @ results[i].R for i in ok])
        if self.k.grids is None:
            inside = self.model.within(moved, p["coarse_q_dist_m"])
        else:
            inside = self.k.grids[1].within(moved, p["coarse_q_dist_m"], NEAR_SPACINGS * self.model.surface_spacing_m)
        q[ok] = inside.reshape(len(ok), len(P)).mean(1)
        return q

    def screen(self, starts, p, stats, keep: int) -> list:
        """The `keep` best starts (R0, t0) after the cheap `icp_screen_stage` (moved to its result)."""
        t = time.perf_counter()
        for _ in starts:
            _count(stats, "screen")
        results = self._register(starts, tuple(p["icp_screen_stage"]), p)
        q = self.qualities(results, p)
        ranked = [(-q[k], k, (r.R, r.t)) for k, r in enumerate(results) if r is not None]
        ranked.sort(key=lambda r: (r[0], r[1]))
        stats["seconds"]["registration"] += time.perf_counter() - t
        return [r[2] for r in ranked[:keep]]

    def coarse(self, starts, p, stats, screen_keep: int = 0):
        """Coarse ICP stage from each start (R0, t0); keeps the best by the probe quality q (share of
        thinned crop points within coarse_q_dist_m of the posed surface). With screen_keep > 0 the
        starts are first screened by the cheaper `icp_screen_stage` and only the best screen_keep go on
        (many orientation starts, e.g. tumbled poses)."""
        if self.src.reason is not None:
            return
        if screen_keep > 0 and len(starts) > screen_keep:
            starts = self.screen(starts, p, stats, screen_keep)
        t = time.perf_counter()
        for _ in starts:
            _count(stats, self.kind)
        results = self._register(starts, tuple(p["icp_stages"][0]), p)
        stats["icp_declined"] += sum(r is None for r in results)
        for res, q in zip(results, self.qualities(results, p)):
            if res is not None and q > self.best_q:
                self.best, self.best_q = res, float(q)
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
        if len(stages) > 1 and self.k.grids is None:
            res = icp_scene_to_model(self.src, self.target[1], res.R, res.t, stages[1:], p["icp_tukey_k_frac"],
                                     p["icp_min_points_n"])
        else:
            for stage in stages[1:]:
                res = self._register([(res.R, res.t)], stage, p, level=1)[0]
                if res is None:
                    break
        stats["seconds"]["registration"] += time.perf_counter() - t
        if res is None:
            return None
        return _score(st, self.k, res, p, stats, self.occluders)


def _score(st, k: OursClass, res, p, stats, occluders):
    t = time.perf_counter()
    model = k.model
    h = score_hypothesis(model, k.views, res.R, res.t, st.scene, p, per_class(p["rmse_max_m"], model.cls), occluders)
    h.fitness = res.fitness
    # Plausibility: the object cannot be sunk into the seabed (a model thicker than its object, within
    # the shape tolerance, sits lower by as much: its surface matches the object's seen top).
    v = model.vertices[::int(p["sink_vertex_stride_n"])] @ res.R.T + res.t
    low = v[np.argmin(v[:, 2])]
    if low[2] < float(st.ground.z_at(low[0], low[1])) - p["sink_max_m"] - shape_tolerance_m(model, p):
        h.score = 0.0
        h.f_s = 0.0
    stats["seconds"]["scoring"] += time.perf_counter() - t
    return h


def _fit(st, k: OursClass, R0, t0, crop_idx, p, stats, occluders=(), kind="refit"):
    """ICP of the crop onto the model from (R0, t0) (all stages, one start), then scoring; None if ICP declines."""
    job = _Job(st, k, crop_idx, p, kind, occluders)
    job.coarse([(R0, t0)], p, stats)
    return job.finish(st, p, stats)


def _z_inits(st, model, xy, crop_idx, p):
    """Start heights (m) of an upright proposal: on the seabed and, when the crop is taller than the class
    by more than `top_start_min_lift_m`, with the object's top at the crop's top."""
    zg = float(st.ground.z_at(xy[0], xy[1]))
    out = [zg]
    if len(crop_idx):
        ztop = float(st.pts[crop_idx, 2].max()) - model.height_m
        if ztop > zg + p["top_start_min_lift_m"]:
            out.append(ztop)
    return out


def _proposal_raster(st, p):
    """Height-above-seabed raster of the unexplained points; cells only explained objects occupy are
    unknown (NaN: an accepted object may hide what is below it)."""
    act = st.active
    xy = np.concatenate([st.seabed_xy, st.pts[act, :2]])
    hv = np.concatenate([np.zeros(len(st.seabed_xy)), st.hab[act]])
    r = height_raster(xy, hv, p["bev_cell_m"], st.x0, st.y0, st.shape)
    if (~act).any():
        ex = height_raster(st.pts[~act, :2], st.hab[~act], p["bev_cell_m"], st.x0, st.y0, st.shape)
        hidden = np.isfinite(ex.h) & ~(r.h > p["ground_min_height_m"])
        r.h[hidden] = np.nan
    return r


def _propose_upright(st, classes, p, rnd, accepted, stats):
    """Round proposals: NCC peaks per class on the map of unexplained points (explained cells unknown)."""
    t = time.perf_counter()
    r = _proposal_raster(st, p)
    occ_min = p["ground_min_height_m"]
    # One correlator for the round: the raster's spectra are shared by the classes, computed first
    # (one task each: their FFTs release the GIL).
    corr = Correlator(r)
    needed = corr.raster_spectra_needed([k.kernels[0].support.shape for k in classes.values()], votes=rnd > 0)
    run_tasks(st.pool, lambda item, part: corr.raster_spectrum(*item, occ_min), needed)

    def peaks(k, part):  # the correlation peaks of one class
        kernels = k.kernels
        rad = int(round(p["proposal_nms_radius_frac"] * k.model.radius_m / p["bev_cell_m"]))
        best, arg, occ = ncc_maps(r, kernels, occ_min, p["proposal_data_min_frac"], corr)
        ii, jj = ncc_peaks(best, occ, p["proposal_ncc_min"], p["proposal_occupancy_min_frac"], rad)
        yaw_of = [kernels[arg[i, j]].yaw_rad for i, j in zip(ii, jj)]
        if rnd > 0:
            # Partly hidden objects: plain occupancy votes of the unexplained points.
            vb, va = vote_map(r, kernels, occ_min, corr)
            vi, vj = ncc_peaks(vb, np.ones_like(vb), p["proposal_vote_min_frac"], 0.0, rad)
            ii, jj = np.r_[ii, vi], np.r_[jj, vj]
            yaw_of += [kernels[va[i, j]].yaw_rad for i, j in zip(vi, vj)]
        return best, ii, jj, yaw_of

    out = []
    for (cls, k), (best, ii, jj, yaw_of) in zip(classes.items(), run_tasks(st.pool, peaks, list(classes.values()))):
        m = k.model
        centres = r.centre(ii, jj)
        near_accepted = p["proposal_accepted_radius_frac"] * m.radius_m
        # The distances to the kept peaks and to the class's accepted objects as one array each (the
        # same values as one np.hypot per pair; the Python loops over pairs held the GIL).
        accepted_xy = np.array([a.t[:2] for a in accepted if a.cls == cls], dtype=np.float64).reshape(-1, 2)
        kept = np.empty((len(centres), 2))
        n_kept = 0
        for (x, y), i, j, yaw in zip(centres, ii, jj, yaw_of):
            if n_kept and (np.hypot(x - kept[:n_kept, 0], y - kept[:n_kept, 1]) < p["proposal_merge_m"]).any():
                continue
            if len(accepted_xy) and (np.hypot(*(accepted_xy - [x, y]).T) < near_accepted).any():
                continue
            kept[n_kept] = x, y
            n_kept += 1
            out.append((cls, np.array([x, y]), yaw, float(best[i, j])))
    stats["seconds"]["proposals"] += time.perf_counter() - t
    return out


def _cap_proposals(props: list, p, rnd: int, stats) -> list:
    """At most `proposal_max_per_round_n` proposals: the best by correlation, in their original order (so a
    cap that does not bite changes nothing); the dropped ones are counted and logged."""
    cap = int(p["proposal_max_per_round_n"])
    if len(props) <= cap:
        return props
    keep = np.sort(np.argsort([-pr[3] for pr in props], kind="stable")[:cap])
    stats["capped"]["proposals"] += len(props) - cap
    log.warning("round %d: %d upright proposals; only the %d correlating best are fitted (proposal_max_per_round_n)",
                rnd, len(props), cap)
    return [props[i] for i in keep]


def _near_boxes(accepted, xy, radius):
    """Boxes of the accepted objects whose footprint circle comes within `radius` (m) of `xy`."""
    if not accepted:
        return []
    b = np.array([a.box for a in accepted])
    near = np.hypot(b[:, 0] - xy[0], b[:, 1] - xy[1]) < radius + 0.5 * np.hypot(b[:, 3], b[:, 4])
    return [a.box for a, ok in zip(accepted, near) if ok]


def _occluders(accepted, model, xy, p):
    """Boxes of the accepted objects that may hide parts of an object of `model`'s class at `xy`."""
    return _near_boxes(accepted, xy, model.radius_m + p["occluder_margin_m"])


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
    n_crop = len(crop)
    if any(n == n_crop and c == cls and np.hypot(*(xy - q)) < p["proposal_merge_m"] for c, q, n in tried):
        stats["proposals_repeated"] += 1
        return None
    tried.append((cls, xy, len(crop)))
    return crop


def _hypotheses_upright(st, classes, proposals, p, rnd, accepted, stats):
    """Upright hypotheses: coarse ICP of every proposal from its starts (seabed/top-aligned heights x
    yaws), class competition among nearby proposals on the coarse quality, shifted restarts and fine
    ICP + scoring for the survivors (the fits on the run's workers)."""
    tasks = []
    for cls, xy, yaw, _ in proposals:
        k = classes[cls]
        m = k.model
        crop = _screened_crop(st, cls, m, xy, p, stats, st.tried)
        if crop is None:
            continue
        n_yaw = 1 if m.symmetric else max(1, int(p["n_yaw_init"]))
        yaws = [yaw + i * m.yaw_period_rad / n_yaw for i in range(n_yaw)]
        starts = [(rot_z(yw), np.r_[xy, z0]) for z0 in _z_inits(st, m, xy, crop, p) for yw in yaws]
        tasks.append((k, crop, _occluders(accepted, m, xy, p), xy, starts))

    def coarse(task, part):
        k, crop, occluders, xy, starts = task
        job = _Job(st, k, crop, p, f"upright{rnd}", occluders, xy)
        job.coarse(starts, p, part)
        return job

    jobs = [j for j in run_tasks(st.pool, coarse, tasks, stats) if j.best is not None]
    # Class competition: near one another, proposals far below the best coarse quality are dropped.
    qs = np.array([j.best_q for j in jobs])
    xys = np.array([j.xy for j in jobs]).reshape(-1, 2)
    survivors = []
    for job in jobs:
        near = np.hypot(*(xys - job.xy).T) < p["class_competition_m"]
        if not job.passes(p) or job.best_q < qs[near].max() - p["class_q_margin"]:
            stats["proposals_outcompeted"] += 1
            continue
        survivors.append(job)

    def finish(job, part):
        job.shift(p, part)
        return job.finish(st, p, part)

    hyps = []
    for job, h in zip(survivors, run_tasks(st.pool, finish, survivors, stats)):
        if h is not None:
            h.round, h.seed_xy = rnd, job.xy
            hyps.append(h)
    return hyps


def _residual_seeds(st, g_idx, p) -> list:
    """Seeds (x, y, is_tip) in one cluster of unexplained points: the peaks of the smoothed point
    density (Gaussian `residual_seed_sigma_m`, peaks at least `residual_seed_sep_m` apart), which sit
    near the middle of each object's visible part even when objects touch or pile up; with
    `residual_height_seeds` the cluster's height maxima (`_height_seeds`, is_tip True); plus the
    cluster's centroid unless a seed is `residual_centroid_sep_m` close."""
    cell = p["residual_seed_cell_m"]
    pad = p["residual_seed_pad_m"]
    xy = st.pts[g_idx, :2]
    lo = np.floor((xy.min(0) - pad) / cell) * cell  # cell-aligned: a crop sees the same cells
    shape = tuple((np.ceil((xy.max(0) + pad - lo) / cell)).astype(int)[::-1])
    j = ((xy[:, 0] - lo[0]) / cell).astype(int)
    i = ((xy[:, 1] - lo[1]) / cell).astype(int)
    dens = np.zeros(shape)
    np.add.at(dens, (i, j), 1.0)
    dens = ndi.gaussian_filter(dens, p["residual_seed_sigma_m"] / cell, mode="constant")
    size = 2 * int(round(p["residual_seed_sep_m"] / cell)) + 1
    peak = (dens >= ndi.maximum_filter(dens, size=size, mode="constant")) & \
        (dens >= p["residual_seed_min_density_frac"] * dens.max())
    pi, pj = np.nonzero(peak)
    order = np.argsort(-dens[pi, pj], kind="stable")[: int(p["residual_max_seeds_n"])]
    seeds = [np.array([lo[0] + (pj[k] + 0.5) * cell, lo[1] + (pi[k] + 0.5) * cell]) for k in order]
    tips = _height_seeds(st.hab[g_idx], i, j, shape, lo, seeds, p) if p["residual_height_seeds"] else []
    c = xy.mean(0)
    out = [(q, False) for q in seeds] + [(q, True) for q in tips]
    if all(np.hypot(*(c - q)) > p["residual_centroid_sep_m"] for q in seeds + tips):
        out.append((c, False))
    return out


def _height_seeds(hab, i, j, shape, lo, seeds, p) -> list:
    """More seeds (x, y) in a cluster of unexplained points: the local maxima of its height above the
    seabed (per `residual_seed_cell_m` cell, maxima at least `residual_seed_sep_m` apart and
    `residual_min_height_m` high), farther than that from every seed in `seeds`, highest first, up to
    `residual_max_seeds_n` in all. In a dumped pile the density is one broad plateau with a few peaks,
    while every element lifts a leg: its own local maximum of height, at every layer."""
    cell = p["residual_seed_cell_m"]
    top = np.full(shape, -np.inf)
    np.maximum.at(top, (i, j), hab)
    size = 2 * int(round(p["residual_seed_sep_m"] / cell)) + 1
    peak = (top >= ndi.maximum_filter(top, size=size, mode="constant", cval=-np.inf)) & \
        (top >= p["residual_min_height_m"])
    pi, pj = np.nonzero(peak)
    out = []
    for k in np.argsort(-top[pi, pj], kind="stable"):
        if len(seeds) + len(out) >= int(p["residual_max_seeds_n"]):
            break
        q = np.array([lo[0] + (pj[k] + 0.5) * cell, lo[1] + (pi[k] + 0.5) * cell])
        if all(np.hypot(*(q - s_)) >= p["residual_seed_sep_m"] for s_ in seeds + out):
            out.append(q)
    return out


def _seeding_points(st, classes, accepted, p) -> np.ndarray:
    """Indices of the unexplained candidate points that may seed tumbled hypotheses. Leftovers of
    accepted objects (points just beyond claim_m of their mesh: feet, edges, noise) are not new
    objects: points within leftover_claim_factor x claim_m of an accepted mesh do not seed."""
    free = st.active.copy()
    margin = p["leftover_margin_m"]
    for a in accepted:
        m = classes[a.cls].model
        idx = _crop(st, a.t[:2], m.radius_m + margin)
        if len(idx):
            idx = idx[points_in_box(st.pts[idx], a.box, margin)]
            free[idx[m.distance((st.pts[idx] - a.t) @ a.R) < p["leftover_claim_factor"] * p["claim_m"]]] = False
    return np.flatnonzero(free)


def pose_extents(model, rots, stride: int) -> list:
    """Per rotation R0 (3,3) of `rots`, the extent of every `stride`-th mesh vertex turned by it
    (canonical frame turned, m): (centre of its bounding box (3,), lowest z, highest z, highest vertex (3,)).
    What `_tumbled_starts` needs of a pose, independent of where it is tried (built once per class)."""
    out = []
    for R0 in rots:
        v = model.vertices[::stride] @ np.asarray(R0).T
        out.append((0.5 * (v.min(0) + v.max(0)), float(v[:, 2].min()), float(v[:, 2].max()), v[np.argmax(v[:, 2])]))
    return out


def _tumbled_starts(st, m, rots, xy, crop, p, tip: bool = False, extents=None) -> list:
    """Starts (R0, t0) of the tumbled poses `rots` at seed `xy`: each pose resting on the seabed, centred
    on the seed, and lifted to the crop's top when the crop is taller than the pose by more than
    `top_start_min_lift_m` (it may rest on others). At a tip seed (a height maximum: a raised leg's
    tip, 0.4-0.7 m off the centre of a leaning pile member) with `tumbled_tip_starts`, instead each
    pose with its highest point under the seed at the crop's top. Poses taller than the crop allows are
    left out. extents: `pose_extents` of `rots` (with `tumbled_vertex_stride_n`), computed here if None."""
    zg = float(st.ground.z_at(xy[0], xy[1]))
    ztop = float(st.pts[crop, 2].max())
    crop_h = float(st.hab[crop].max())
    if extents is None:
        extents = pose_extents(m, rots, int(p["tumbled_vertex_stride_n"]))
    starts = []
    for R0, (c, z_lo, z_hi, top) in zip(rots, extents):
        if crop_h < p["proposal_min_height_frac"] * (z_hi - z_lo):
            continue  # the crop is too low for the object in this pose
        if tip and p["tumbled_tip_starts"]:
            starts.append((R0, np.array([xy[0] - top[0], xy[1] - top[1], ztop - top[2]])))
            continue
        base = np.array([xy[0] - c[0], xy[1] - c[1], zg - z_lo])
        starts.append((R0, base))
        lift = ztop - z_hi - base[2]
        if lift > p["top_start_min_lift_m"]:
            starts.append((R0, base + [0.0, 0.0, lift]))
    return starts


def _tumbled_tries(st, classes, p, rnd, accepted, stats) -> list:
    """Tumbled-orientation tries (class, crop, occluders, seed xy, starts) on clusters of unexplained
    points (seeds: `_residual_seeds`), at most `proposal_max_per_round_n`."""
    idx_act = _seeding_points(st, classes, accepted, p)
    if len(idx_act) == 0:
        return []
    tasks, tries = [], 0
    for grp in clusters(st.pts[idx_act, :2], p["residual_cluster_cell_m"], p["residual_min_points_n"]):
        g = idx_act[grp]
        if float(st.hab[g].max()) < p["residual_min_height_m"]:
            continue
        for xy, tip in _residual_seeds(st, g, p):
            for cls, k in classes.items():
                m = k.model
                if not k.tumbled:
                    continue
                if tries >= int(p["proposal_max_per_round_n"]):
                    stats["capped"]["tumbled_rounds"] += 1
                    log.warning("round %d: %d tumbled seed tries; the other seeds are left (proposal_max_per_round_n)",
                                rnd, tries)
                    return tasks
                tries += 1
                crop = _screened_crop(st, cls, m, xy, p, stats, st.tried_tumbled)
                if crop is None:
                    continue
                starts = _tumbled_starts(st, m, k.tumbled, xy, crop, p, tip, k.tumbled_extents)
                if not starts:
                    stats["windows_skipped"] += 1
                    continue
                tasks.append((k, crop, _occluders(accepted, m, xy, p), xy, starts))
    return tasks


def _hypotheses_tumbled(st, classes, p, rnd, accepted, stats) -> list:
    """Tumbled-orientation hypotheses of the tries of `_tumbled_tries`: screened coarse ICP from their
    starts, shifted restarts, fine ICP and scoring, one task each on the run's workers."""
    tasks = _tumbled_tries(st, classes, p, rnd, accepted, stats)

    def fit(task, part):
        k, crop, occluders, xy, starts = task
        job = _Job(st, k, crop, p, "tumbled", occluders, xy)
        job.coarse(starts, p, part, screen_keep=int(p["tumbled_screen_keep_n"]))
        if not job.passes(p):
            return None
        job.shift(p, part, p["tumbled_shift_q_min"])
        return job.finish(st, p, part)

    hyps = []
    for task, h in zip(tasks, run_tasks(st.pool, fit, tasks, stats)):
        if h is not None:
            h.round, h.seed_xy = rnd, task[3]
            hyps.append(h)
    return hyps


def _penetration(h, a, classes, p) -> float:
    """Share of h's surface samples (every penetration_surface_stride_n-th) inside accepted object a's mesh."""
    mh, ma = classes[h.cls].model, classes[a.cls].model
    if np.hypot(*(h.t[:2] - a.t[:2])) > mh.radius_m + ma.radius_m:
        return 0.0
    s = mh.surface[::int(p["penetration_surface_stride_n"])] @ h.R.T + h.t
    return float(ma.inside((s - a.t) @ a.R).mean())


def _claim(st, h, classes, p):
    """Indices of candidate points the accepted hypothesis explains (within claim_m of its mesh)."""
    m = classes[h.cls].model
    idx = _crop(st, h.t[:2], m.radius_m + p["claim_crop_margin_m"], only_active=True)
    if len(idx) == 0:
        return idx
    d = tolerant_distance(m, (st.pts[idx] - h.t) @ h.R, p)
    return idx[d < p["claim_m"]]


def _own(st, h, classes, p):
    """Mark the points an accepted hypothesis explains (inliers + claimed) as owned by it."""
    claimed = _claim(st, h, classes, p)
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
    """Accepted objects h may replace: those owning at least `replace_owner_min_frac` of h's inliers, if h
    scores at least `replace_factor` times each of them (a tumbled big tetrapod over a small one
    accepted first)."""
    inl = h.cand[h.inl]
    if len(inl) == 0:
        return []
    owners = st.owner[inl]
    ids, counts = np.unique(owners[owners >= 0], return_counts=True)
    conf = [a for a in accepted if a.uid in set(ids[counts >= p["replace_owner_min_frac"] * len(inl)].tolist())]
    if conf and all(h.score >= p["replace_factor"] * a.score for a in conf):
        return conf
    return []


def _acceptable(st, h, classes, accepted, p, rmse_max):
    """Whether the best pending hypothesis h may be accepted, and the accepted objects it replaces.

    Returns (ok, new_ok, replace): new_ok when enough of its inliers are unexplained; replace the
    accepted objects it may replace otherwise (`_replaceable`); ok when it explains something new (or
    replaces), its RMSE is within the class limit and it interpenetrates no other accepted object."""
    replace = []
    new_ok = new_fraction(h, st.active) >= p["new_min_frac"]
    if not new_ok and p["replace_factor"] > 0:
        replace = _replaceable(st, h, accepted, p)
    others = [a for a in accepted if all(a is not r for r in replace)]
    lim = p["penetration_max_frac"]
    ok = ((new_ok or bool(replace)) and h.rmse_m <= rmse_max[h.cls]
          and all(_penetration(h, a, classes, p) <= lim and _penetration(a, h, classes, p) <= lim for a in others))
    return ok, new_ok, replace


def _inliers_lost(h, gone) -> float:
    """Share of h's inliers that a newly accepted object took (`gone`); 0 without inliers."""
    inl = h.cand[h.inl]
    return float(gone[inl].mean()) if len(inl) else 0.0


def _update_pending(st, classes, pending, accepted, gone, changed, p, stats, rmse_max):
    """Pending hypotheses that shared points a newly accepted object explained (`changed`): refitted on
    what is left when they lost more than `refit_lost_min_frac` of their candidates to it (`gone`; at
    most `refits_max_n` times each) unless more than `refit_inliers_lost_max_frac` of their inliers, else
    re-scored. A hypothesis that lost that much of its inliers was another explanation of the object
    just accepted, not of a neighbour: what is left of its crop is proposed again in the next round."""
    refit, rest = [], []
    for j, o in enumerate(pending):
        if len(o.cand) == 0:
            continue
        if not changed[o.cand].any():
            continue
        lost = gone[o.cand].mean()
        if lost > p["refit_lost_min_frac"] and o.n_refits < p["refits_max_n"] \
                and _inliers_lost(o, gone) <= p["refit_inliers_lost_max_frac"]:
            refit.append(j)
        else:
            rest.append(j)

    def fit(j, part):
        o = pending[j]
        k = classes[o.cls]
        crop = _crop(st, o.t[:2], k.model.radius_m + p["crop_margin_m"])
        if len(crop) < p["icp_min_points_n"]:
            return None
        return _fit(st, k, o.R, o.t, crop, p, part, _occluders(accepted, k.model, o.t[:2], p), kind="refit")

    for j, ref in zip(refit, run_tasks(st.pool, fit, refit, stats)):
        if ref is None:
            rest.append(j)
            continue
        o = pending[j]
        ref.round, ref.seed_xy, ref.n_refits = o.round, o.seed_xy, o.n_refits + 1
        pending[j] = ref
        stats["refits"] += 1
    for j in rest:  # re-scoring is cheap: in any order
        o = pending[j]
        rescore(o, st.active, rmse_max[o.cls], p)


def _select(st, classes, pending, accepted, p, stats):
    """Greedy explain-away over pending hypotheses; returns the newly accepted ones.

    The best pending hypothesis is accepted when its score reaches `accept_min` and `_acceptable`
    allows it. Its points are then explained (the objects it replaces give theirs back); pending
    hypotheses that shared them are refitted or re-scored (`_update_pending`).
    """
    t = time.perf_counter()
    new_acc = []
    rmse_max = {c: per_class(p["rmse_max_m"], c) for c in classes}
    if p["overhang_max_frac"] > 0:  # objects under others (piles, stacks) keep their score
        support_overhangs(pending, len(st.active))
    support_neighbours(pending, pending, len(st.active), rmse_max, p)
    for h in pending:
        rescore(h, st.active, rmse_max[h.cls], p)
    while pending:
        i = int(np.argmax([h.score for h in pending]))
        h = pending[i]
        if h.score < p["accept_min"]:
            break
        pending.pop(i)
        ok, new_ok, replace = _acceptable(st, h, classes, accepted, p, rmse_max)
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
        idx = _own(st, h, classes, p)
        gone[idx] = True
        changed[idx] = True
        _update_pending(st, classes, pending, accepted, gone, changed, p, stats, rmse_max)
    st.rejected.extend(pending)
    stats["seconds"]["selection"] += time.perf_counter() - t
    return new_acc


def _output(st, accepted, p) -> list:
    """Accepted hypotheses (accepted=True), then, with keep_rejected, the others scoring at least score_min
    that duplicate none of those kept before them, down-weighted by rejected_score_factor."""
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


def detect_ours(xyz: np.ndarray, classes: dict[str, OursClass], p: dict, stats: dict, pool=None) -> list:
    """Run the `ours` pipeline on local-frame points (N,3, m) with the per-class data of
    `prepare_classes`; returns scored Hypothesis objects (accepted ones first, then down-weighted
    others) with `accepted` set on each, and adds its counts and per-stage seconds to `stats`.
    pool: worker threads for the independent fits of a round (`tasks.worker_pool`); the result is the
    same with or without."""
    t = time.perf_counter()
    # The tree over every point does not depend on the seabed: built on a worker meanwhile (it releases the GIL).
    all_tree = pool.submit(cKDTree, xyz[:, :2]) if pool is not None else None
    ground = seabed(xyz, p)
    st = _State(xyz, ground, p, pool, None if all_tree is None else all_tree.result())
    stats["replaced"] = 0
    stats["proposals_repeated"] = 0
    stats["proposals_outcompeted"] = 0
    stats["capped"] = {"proposals": 0, "tumbled_rounds": 0}
    stats["n_candidate_points"] = int(len(st.pts))
    stats["seconds"]["ground"] += time.perf_counter() - t
    log.info("seabed: %d points, %d candidates above it, %.1f s", len(xyz), len(st.pts), time.perf_counter() - t)
    if len(st.pts) < p["icp_min_points_n"]:
        return []
    accepted: list[Hypothesis] = []
    for rnd in range(int(p["proposal_max_rounds_n"])):
        t = time.perf_counter()
        props = _cap_proposals(_propose_upright(st, classes, p, rnd, accepted, stats), p, rnd, stats)
        pending = _hypotheses_upright(st, classes, props, p, rnd, accepted, stats)
        if rnd > 0 and p["tumbled_inits"]:
            pending += _hypotheses_tumbled(st, classes, p, rnd, accepted, stats)
        stats["hypotheses"] += len(pending)
        n_pending = len(pending)
        new = _select(st, classes, pending, accepted, p, stats)
        stats["accepted_per_round"].append(len(new))
        log.info("round %d: %d proposals, %d hypotheses, %d accepted (%d in all), %d ICP runs so far, %.1f s", rnd,
                 len(props), n_pending, len(new), len(accepted), stats["icp_runs"], time.perf_counter() - t)
        if not new and rnd > 0:
            break
    return _output(st, accepted, p)
