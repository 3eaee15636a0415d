"""Greedy matching of predictions to ground truth, nuScenes style (devkit `accumulate`, matching part).

For one class the predictions of all scenes are pooled, scenes in the order given (evaluate passes them
sorted by scene id, so results do not depend on dict order) and, within a scene, in file order. They
are ranked exactly like devkit 1.2.0 does, `sorted((score, i) for i, score in enumerate(scores))[::-1]`:
score descending and, among equal scores, the prediction pooled LATER comes first (this is not a stable
argsort of -score). Each prediction in turn takes the nearest not-yet-taken ground truth of its class in
its own scene by 2D centre distance (the first one in scene order on equal distances) and is a true
positive only if that distance is strictly below the threshold (`distance < dist_th_m`); a prediction
exactly at the threshold is a false positive.

Don't-care objects (ground truth flagged `ignore`, e.g. objects in piles when a study leaves them
out): they are not counted as ground truth, and a prediction that finds no free counted object within
the threshold but lies within it of a don't-care object of its class is ignored, neither true nor
false positive (like COCO's crowd regions: one don't-care object may absorb several predictions). The
devkit has no such objects; without them the matching is the devkit's.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import center_distance_matrix


@dataclass
class PooledClass:
    """The predictions and ground truth of one class, pooled over scenes (boxes `[x,y,z,l,w,h,yaw]`, m/rad).

    pred_boxes (N,7), pred_scores (N,), pred_scene (N,) index into `scenes`, pred_local (N,) index of the
    prediction within its scene's predictions of this class; gt_boxes[s] (G_s,7) the scene's ground truth
    of this class in scene order; distances[s] (P_s, G_s) centre distances (m) of that scene's predictions
    of this class to its ground truth.
    """

    cls: str
    scenes: list[str]
    pred_boxes: np.ndarray
    pred_scores: np.ndarray
    pred_scene: np.ndarray
    pred_local: np.ndarray
    gt_boxes: list[np.ndarray]
    distances: list[np.ndarray] = field(repr=False)
    #: Per scene, (G_s,) bool: the ground-truth object is don't-care (not counted; see module doc).
    gt_ignore: list[np.ndarray] = field(default_factory=list, repr=False)

    @property
    def n_gt(self) -> int:
        """Number of counted (not don't-care) ground-truth objects of the class over all scenes."""
        if not self.gt_ignore:
            return int(sum(len(g) for g in self.gt_boxes))
        return int(sum(int((~ig).sum()) for ig in self.gt_ignore))

    @property
    def n_pred(self) -> int:
        """Number of predictions of the class over all scenes."""
        return int(len(self.pred_scores))


@dataclass
class ClassMatch:
    """Result of matching one class at one distance threshold; arrays are in ranking order (N,).

    order: pooled prediction indices in ranking order; scores: their scores; is_tp: matched or not;
    gt_scene / gt_index: scene index and index within that scene's ground truth of this class of the
    matched object (-1 for false positives); n_gt: number of ground-truth objects of the class.
    """

    cls: str
    dist_th_m: float
    n_gt: int
    order: np.ndarray
    scores: np.ndarray
    is_tp: np.ndarray
    gt_scene: np.ndarray
    gt_index: np.ndarray
    #: (N,) bool: matched a don't-care object only (neither TP nor FP); all False without them.
    is_ignored: np.ndarray = None

    def __post_init__(self):
        if self.is_ignored is None:
            self.is_ignored = np.zeros(len(self.is_tp), dtype=bool)

    @property
    def n_tp(self) -> int:
        """Number of true positives."""
        return int(self.is_tp.sum())


def _boxes(items) -> np.ndarray:
    return np.array([np.asarray(it["box"], dtype=np.float64) for it in items], dtype=np.float64).reshape(-1, 7)


def pool_class(gt_by_scene: dict, dets_by_scene: dict, cls: str, scenes: list[str]) -> PooledClass:
    """Pool the ground truth and predictions of class `cls` over `scenes`, in that scene order.

    gt_by_scene[scene]: list of ground-truth objects (dicts with `cls`, `box`) already filtered to the
    ones to evaluate; dets_by_scene[scene]: list of detections (dicts with `cls`, `box`, `score`). Scenes
    missing from either dict have no objects / no predictions.
    """
    boxes, scores, scene_idx, local_idx, gts, dists, ignore = [], [], [], [], [], [], []
    for s, sid in enumerate(scenes):
        objs = [o for o in gt_by_scene.get(sid, ()) if o["cls"] == cls]
        g = _boxes(objs)
        ignore.append(np.array([bool(o.get("ignore", False)) for o in objs], dtype=bool))
        dets = [d for d in dets_by_scene.get(sid, ()) if d["cls"] == cls]
        p = _boxes(dets)
        gts.append(g)
        dists.append(center_distance_matrix(p[:, :2], g[:, :2]))
        boxes.append(p)
        scores.extend(float(d["score"]) for d in dets)
        scene_idx.extend([s] * len(dets))
        local_idx.extend(range(len(dets)))
    return PooledClass(
        cls=cls,
        scenes=list(scenes),
        pred_boxes=np.vstack(boxes) if boxes else np.zeros((0, 7)),
        pred_scores=np.asarray(scores, dtype=np.float64),
        pred_scene=np.asarray(scene_idx, dtype=np.int64),
        pred_local=np.asarray(local_idx, dtype=np.int64),
        gt_boxes=gts,
        distances=dists,
        gt_ignore=ignore,
    )


def ranking_order(scores) -> np.ndarray:
    """Indices of scores (N,) ranked as the devkit ranks them: score descending, ties by index descending."""
    s = np.asarray(scores, dtype=np.float64)
    return np.lexsort((np.arange(len(s)), s))[::-1]


def match_class(pooled: PooledClass, dist_th_m: float) -> ClassMatch:
    """Greedy nearest-centre matching of a pooled class at threshold dist_th_m (m); see the module doc."""
    order = ranking_order(pooled.pred_scores)
    n = len(order)
    is_tp = np.zeros(n, dtype=bool)
    gt_scene = np.full(n, -1, dtype=np.int64)
    gt_index = np.full(n, -1, dtype=np.int64)
    is_ignored = np.zeros(n, dtype=bool)
    ignore = pooled.gt_ignore or [np.zeros(len(g), dtype=bool) for g in pooled.gt_boxes]
    # Don't-care objects are never free to take: they only absorb predictions that find nothing else.
    taken = [ig.copy() for ig in ignore]
    for rank, k in enumerate(order):
        s = int(pooled.pred_scene[k])
        if len(taken[s]) == 0:
            continue
        row = pooled.distances[s][pooled.pred_local[k]]
        dist = np.where(taken[s], np.inf, row)
        j = int(np.argmin(dist))  # first minimum in scene order, as the devkit's strict '<' scan
        if dist[j] < dist_th_m:
            taken[s][j] = True
            is_tp[rank] = True
            gt_scene[rank] = s
            gt_index[rank] = j
        elif ignore[s].any() and np.min(np.where(ignore[s], row, np.inf)) < dist_th_m:
            is_ignored[rank] = True
    return ClassMatch(
        cls=pooled.cls,
        dist_th_m=float(dist_th_m),
        n_gt=pooled.n_gt,
        order=order,
        scores=pooled.pred_scores[order],
        is_tp=is_tp,
        gt_scene=gt_scene,
        gt_index=gt_index,
        is_ignored=is_ignored,
    )
