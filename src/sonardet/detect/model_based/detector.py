"""Public entry points of the model-based (training-free) detector: :class:`ModelBasedDetector` (class
models built once, then called per point cloud) and :func:`detect` (one call, one cloud).

Input: a float64 point cloud (N,3) in metres (scene frame or survey CRS, z up), the template scans
(`sonardet.io.templates.TemplateViews`) and the object models (`sonardet.objects.ObjectInfo`) of each
class to detect. Georeferenced input (|x| or |y| > 1e5 m, e.g. UTM) is shifted to a local origin
(float64, `sonardet.io.origin.choose_origin`) before any geometry, and the outputs are shifted back,
so the same survey gives the same detections in either frame.

Output: a list of detections {cls, box [x,y,z,l,w,h,yaw] (m, rad; the evaluation box of the posed
mesh, `sonardet.objects.canonical_box`), pose {t (m), q (w,x,y,z)} (canonical object frame -> input
frame), score (higher = more confident; used for AP ranking), extras {rmse_m, fitness, f_t, f_s,
accepted, variant, ...}}, sorted by score, and a statistics dict (windows, skipped windows, ICP runs,
per-stage seconds).
"""

from __future__ import annotations

import time
import warnings

import numpy as np
import open3d as o3d

from ...io.origin import choose_origin, finite_xyz
from .models import ClassModel, build_class_model
from .ours import detect_ours, prepare_classes
from .paper import RANKING_KEYS, detect_paper_rankings
from .params import resolve_params
from .tasks import worker_pool

_STAGES = ("ground", "models", "proposals", "registration", "scoring", "selection")


def new_stats(variant: str) -> dict:
    """An empty statistics dict (what a detector call returns next to the detections; seconds in s)."""
    return {
        "variant": variant, "n_points": 0, "n_candidate_points": 0, "windows": 0, "windows_skipped": 0,
        "windows_reused": 0, "icp_runs": 0, "icp_runs_by_kind": {}, "icp_declined": 0, "hypotheses": 0, "refits": 0,
        "accepted_per_round": [], "capped": {},
        "n_detections": 0, "origin": [0.0, 0.0, 0.0], "seconds": {k: 0.0 for k in _STAGES + ("total",)},
    }


def class_models(templates: dict, objects: dict, p: dict) -> dict[str, ClassModel]:
    """The ClassModel (canonical frame, m) of each class in `objects`, built from its template scans
    and mesh with the resolved parameters `p` (surface_spacing_m; seed of the surface sampling).

    Raises ValueError when a class has no template views or its templates belong to another class.
    """
    out = {}
    for cls, obj in objects.items():
        if cls not in templates:
            raise ValueError(f"no template scans for class {cls!r}: templates hold {sorted(templates)}; "
                             f"build results/templates/{cls}.npz or drop the class")
        tv = templates[cls]
        if getattr(tv, "cls", cls) != cls:
            raise ValueError(f"templates[{cls!r}] holds scans of class {tv.cls!r}")
        if len(tv.xyz) == 0 or tv.n_views == 0:
            raise ValueError(f"template scans of class {cls!r} hold no points")
        o3d.utility.random.seed(int(p["seed"]))
        out[cls] = build_class_model(tv, obj, p["surface_spacing_m"])
    return out


def _detection(h, origin: np.ndarray, variant: str) -> dict | None:
    """One output detection (input frame) of a scored hypothesis (local frame), None if not finite."""
    if not (np.all(np.isfinite(h.box)) and np.all(np.isfinite(h.t)) and np.isfinite(h.score)):
        return None
    box = np.asarray(h.box, dtype=np.float64).copy()
    box[:3] += origin
    return {
        "cls": h.cls,
        "box": [float(v) for v in box],
        "pose": {"t": [float(v) for v in h.t + origin], "q": [float(v) for v in h.q]},
        "score": float(h.score),
        "extras": {"rmse_m": float(h.rmse_m), "fitness": float(h.fitness), "f_t": float(h.f_t),
                   "f_s": float(h.f_s), "g_h": float(h.g_h), "accepted": bool(getattr(h, "accepted", True)),
                   "round": int(h.round), "upright": bool(h.upright), "variant": variant},
    }


class ModelBasedDetector:
    """The model-based detector of one variant for a set of classes, ready to run on point clouds.

    templates: class -> TemplateViews (canonical-frame template scans). objects: class -> ObjectInfo
    (meshes, symmetry; the classes to detect are the keys of `objects`, in that order). params:
    overrides of the variant's defaults (`params.DEFAULTS` for 'ours', `params.PAPER` for 'paper');
    unknown keys raise. variant: 'ours' or 'paper'.

    The class models (mesh surface samples, ray-casting scenes) and, for 'ours', the per-class data
    derived from them (ICP targets, BEV kernels, tumbled rotations, thinned template views) are built
    here once; `build_seconds` says how long that took (s). Calling the detector on a cloud
    (`detector(xyz)`) runs the pipeline; the same cloud gives the same detections on every call.
    threads: worker threads of one call ('ours' fits a round's proposals on them, `tasks`; 'paper'
    ignores it); the detections and counts are the same for any number, only the time differs.
    Raises ValueError for an unknown variant or parameter, no classes, a class without templates, or
    threads < 1.
    """

    def __init__(self, templates: dict, objects: dict, params: dict | None = None, variant: str = "ours",
                 threads: int = 1):
        t = time.perf_counter()
        if int(threads) < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        self.threads = int(threads)
        self.variant = variant
        self.params = resolve_params(params, variant)
        if not objects:
            raise ValueError("objects is empty: give at least one class to detect")
        self.models = class_models(templates, objects, self.params)
        self.ours_classes = prepare_classes(self.models, self.params) if variant == "ours" else None
        self.build_seconds = time.perf_counter() - t

    @property
    def classes(self) -> list[str]:
        """The classes this detector looks for."""
        return list(self.models)

    def __call__(self, xyz: np.ndarray) -> tuple[list[dict], dict]:
        """Detect objects in a point cloud xyz (N,3) float64 (m; scene/local frame or a survey CRS,
        shifted internally if large). Returns (detections, stats), see :func:`detect`; stats' seconds
        cover this call only (models: 0, the detector was built before).

        An empty cloud gives no detections and a warning; NaN/Inf points or a wrong shape raise ValueError.
        """
        return self._run(xyz, [self.params])[0]

    def rankings(self, xyz: np.ndarray, overrides: list[dict]) -> list[tuple[list[dict], dict]]:
        """The 'paper' detections of several settings in one run: this detector's parameters with each
        of `overrides` on top (keys of `paper.RANKING_KEYS` only: acceptance, score, duplicate removal),
        sharing the seabed, the windows and their registration. Returns one (detections, stats) per
        override, each the detections a detector of those settings gives alone; a stats dict holds the
        shared stages' counts and seconds and its own scoring and selection, and its `total` is the
        call's wall time less the other settings' own seconds (what it would have taken alone).
        Raises ValueError for the 'ours' variant or an override outside RANKING_KEYS."""
        if self.variant != "paper":
            raise ValueError(f"only the 'paper' variant shares a run between rankings, not {self.variant!r}")
        bad = sorted({k for o in overrides for k in o} - set(RANKING_KEYS))
        if bad:
            raise ValueError(f"rankings may override only {RANKING_KEYS}, not {bad}")
        return self._run(xyz, [resolve_params({**self.params, **o}, "paper") for o in overrides])

    def _run(self, xyz: np.ndarray, settings: list[dict]) -> list[tuple[list[dict], dict]]:
        """(detections, stats) of each of `settings` (resolved parameters; several only for 'paper',
        differing in RANKING_KEYS) on the cloud xyz."""
        t_all = time.perf_counter()
        p = self.params
        stats = [new_stats(self.variant) for _ in settings]
        a = finite_xyz(xyz)
        for s in stats:
            s["n_points"] = int(len(a))
        need = max(3, int(p["icp_min_points_n"]))
        if len(a) < need:
            # No fit can use fewer points than `icp_min_points_n`: the result would be empty anyway, and
            # a seabed plane through a handful of points may come out as a wall.
            warnings.warn(f"model-based detection on a cloud of {len(a)} point(s), fewer than the {need} one fit "
                          "needs (icp_min_points_n): nothing to detect", stacklevel=3)
            for s in stats:
                s["seconds"]["total"] = time.perf_counter() - t_all
            return [([], s) for s in stats]
        origin = choose_origin(a)
        local = a - origin
        o3d.utility.random.seed(int(p["seed"]))
        # One Open3D thread: ICP on a few hundred points is faster without OpenMP, and a single thread
        # sums in a fixed order, so the same input gives the same bytes.
        threads = o3d.utility.get_max_threads()
        o3d.utility.set_max_threads(1)
        try:
            if self.variant == "ours":
                with worker_pool(self.threads) as pool:
                    hyps = [detect_ours(local, self.ours_classes, p, stats[0], pool)]
            else:
                hyps = detect_paper_rankings(local, self.models, settings, stats)
        finally:
            o3d.utility.set_max_threads(threads)
        out = []
        for h, s in zip(hyps, stats):
            dets = [d for d in (_detection(x, origin, self.variant) for x in h) if d is not None]
            dets.sort(key=lambda d: -d["score"])
            s["origin"] = [float(v) for v in origin]
            s["n_detections"] = len(dets)
            out.append((dets, s))
        wall = time.perf_counter() - t_all
        own = [s["seconds"]["scoring"] + s["seconds"]["selection"] for s in stats]
        for s, o in zip(stats, own):
            s["seconds"]["total"] = wall - (sum(own) - o)
        return out


def detect(xyz: np.ndarray, templates: dict, objects: dict, params: dict | None = None,
           variant: str = "ours") -> tuple[list[dict], dict]:
    """Detect reef elements in one point cloud with the model-based pipeline: builds a
    :class:`ModelBasedDetector` and runs it once (to run one setting on many clouds, build the
    detector once and call it per cloud).

    xyz: (N,3) float64 points (m), scene/local frame or a survey CRS (shifted internally if large).
    templates, objects, params, variant: see :class:`ModelBasedDetector`.

    Returns (detections, stats): detections sorted by descending score, each {cls, box [x,y,z,l,w,h,yaw],
    pose {t, q (w,x,y,z)}, score, extras {rmse_m, fitness, f_t, f_s, accepted, round, upright, variant}};
    ours outputs accepted objects (score >= accept_min) and, down-weighted below them, the other
    hypotheses that duplicate none (extras.accepted False). stats: n_points, n_candidate_points (above
    the seabed), windows (paper: sliding windows; ours: proposals tried, class by class), windows_skipped
    (too few points / too low), windows_reused (paper: windows holding exactly an earlier window's
    points, given its fit without registering again), icp_runs (ICP calls; icp_runs_by_kind splits them), icp_declined
    (degenerate input), hypotheses, refits, accepted_per_round, replaced, proposals_repeated,
    proposals_outcompeted (ours), capped (what the time bounds left out: ours {proposals, tumbled_rounds},
    `proposal_max_per_round_n`; paper {windows}, `window_max_n`), n_detections, origin (the local origin
    used, input frame), seconds {ground, models (building the detector), proposals, registration,
    scoring, selection, total} (with worker threads, registration and scoring are summed over the
    threads and may add up to more than `total`, the wall time).
    An empty cloud gives no detections and a warning; NaN/Inf points, a wrong shape, an unknown
    variant or parameter, or a class without templates raise ValueError.
    """
    detector = ModelBasedDetector(templates, objects, params, variant)
    dets, stats = detector(xyz)
    stats["seconds"]["models"] += detector.build_seconds
    stats["seconds"]["total"] += detector.build_seconds
    return dets, stats
