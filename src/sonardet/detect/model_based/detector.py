"""Public entry point of the model-based (training-free) detector: :func:`detect`.

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

import hashlib
import time
import warnings

import numpy as np
import open3d as o3d

from ...io.origin import choose_origin, finite_xyz
from .models import ClassModel, build_class_model
from .ours import detect_ours
from .paper import detect_paper
from .params import resolve_params

_MODEL_CACHE: dict = {}
_STAGES = ("ground", "models", "proposals", "registration", "scoring", "selection")


def new_stats(variant: str) -> dict:
    """An empty statistics dict (what `detect` returns next to the detections)."""
    return {
        "variant": variant, "n_points": 0, "n_candidate_points": 0, "windows": 0, "windows_skipped": 0,
        "icp_runs": 0, "icp_runs_by_kind": {}, "icp_declined": 0, "hypotheses": 0, "refits": 0,
        "accepted_per_round": [],
        "n_detections": 0, "origin": [0.0, 0.0, 0.0], "seconds": {k: 0.0 for k in _STAGES + ("total",)},
    }


def _digest(*arrays) -> str:
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def class_models(templates: dict, objects: dict, p: dict) -> dict[str, ClassModel]:
    """Build (or fetch from a process cache) the ClassModel of each class in `objects`.

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
        key = (cls, _digest(obj.mesh.vertices, obj.mesh.faces, tv.xyz, tv.view), p["surface_spacing_m"],
               p["template_voxel_m"], p["seed"])
        if key not in _MODEL_CACHE:
            o3d.utility.random.seed(int(p["seed"]))
            _MODEL_CACHE[key] = build_class_model(tv, obj, p["surface_spacing_m"], p["template_voxel_m"])
        out[cls] = _MODEL_CACHE[key]
    return out


def detect(xyz: np.ndarray, templates: dict, objects: dict, params: dict | None = None,
           variant: str = "ours") -> tuple[list[dict], dict]:
    """Detect reef elements in a point cloud with the model-based pipeline.

    xyz: (N,3) float64 points (m), scene/local frame or a survey CRS (shifted internally if large).
    templates: class -> TemplateViews (canonical-frame template scans). objects: class -> ObjectInfo
    (meshes, symmetry; the classes to detect are the keys of `objects`). params: overrides of the
    variant's defaults (`params.DEFAULTS` for 'ours', `params.PAPER` for 'paper'); unknown keys raise.
    variant: 'ours' or 'paper'.

    Returns (detections, stats): detections sorted by descending score, each {cls, box [x,y,z,l,w,h,yaw],
    pose {t, q (w,x,y,z)}, score, extras {rmse_m, fitness, f_t, f_s, accepted, round, upright, variant}};
    ours outputs accepted objects (score >= accept_min) and, down-weighted below them, the other
    hypotheses that duplicate none (extras.accepted False). stats: n_points, n_candidate_points (above
    the seabed), windows (paper: sliding windows; ours: proposals tried, class by class), windows_skipped
    (too few points / too low), icp_runs (ICP calls; icp_runs_by_kind splits them), icp_declined
    (degenerate input), hypotheses, refits, accepted_per_round, replaced, proposals_repeated,
    proposals_outcompeted (ours), n_detections, origin (the local origin used, input frame), seconds
    {ground, models, proposals, registration, scoring, selection, total}.
    An empty cloud gives no detections and a warning; NaN/Inf points, a wrong shape, an unknown
    variant or parameter, or a class without templates raise ValueError.
    """
    t_all = time.perf_counter()
    p = resolve_params(params, variant)
    stats = new_stats(variant)
    if not objects:
        raise ValueError("objects is empty: give at least one class to detect")
    a = finite_xyz(xyz)
    t = time.perf_counter()
    models = class_models(templates, objects, p)
    stats["seconds"]["models"] += time.perf_counter() - t
    stats["n_points"] = int(len(a))
    if len(a) < 3:
        warnings.warn(f"model-based detection on a cloud of {len(a)} point(s): nothing to detect", stacklevel=2)
        stats["seconds"]["total"] = time.perf_counter() - t_all
        return [], stats
    origin = choose_origin(a)
    local = a - origin
    o3d.utility.random.seed(int(p["seed"]))
    run = detect_ours if variant == "ours" else detect_paper
    # One Open3D thread: ICP on a few hundred points is faster without OpenMP, and a single thread
    # sums in a fixed order, so the same input gives the same bytes.
    threads = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(1)
    try:
        hyps = run(local, models, p, stats)
    finally:
        o3d.utility.set_max_threads(threads)
    dets = []
    for h in hyps:
        if not (np.all(np.isfinite(h.box)) and np.all(np.isfinite(h.t)) and np.isfinite(h.score)):
            continue
        box = np.asarray(h.box, dtype=np.float64).copy()
        box[:3] += origin
        dets.append({
            "cls": h.cls,
            "box": [float(v) for v in box],
            "pose": {"t": [float(v) for v in h.t + origin], "q": [float(v) for v in h.q]},
            "score": float(h.score),
            "extras": {"rmse_m": float(h.rmse_m), "fitness": float(h.fitness), "f_t": float(h.f_t),
                       "f_s": float(h.f_s), "accepted": bool(getattr(h, "accepted", True)),
                       "round": int(h.round), "upright": bool(h.upright), "variant": variant},
        })
    dets.sort(key=lambda d: -d["score"])
    stats["origin"] = [float(v) for v in origin]
    stats["n_detections"] = len(dets)
    stats["seconds"]["total"] = time.perf_counter() - t_all
    return dets, stats
