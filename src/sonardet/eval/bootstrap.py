"""Uncertainty of mAP: a paired bootstrap over scenes.

The nuScenes matching of one prediction depends only on the predictions and ground truth of its own
scene (a prediction can only take a ground-truth object of its scene, and within a scene the greedy
order is the score order), so every prediction's true/false-positive flag is fixed once per scene.
A resample of scenes (drawn with replacement) then only re-pools those flags: the predictions of the
drawn scenes, each scene as often as it was drawn, ranked by score, give the precision/recall curve
and the AP exactly as :func:`sonardet.eval.evaluate` computes them for that multiset of scenes. This
is what makes 1000+ resamples of several methods cheap (no re-matching); the devkit offers no
bootstrap.

Paired: every method is scored on the same resamples, so the difference of two methods gets its own
interval (much narrower than the two intervals suggest when the methods agree on which scenes are
hard). Percentile intervals; seeded (numpy PCG64), so a config gives the same bytes.
"""

from __future__ import annotations

import numpy as np

from .ap import average_precision, interpolated_pr
from .matching import match_class, pool_class, ranking_order

__all__ = ["SceneFlags", "bootstrap_map", "interval", "scene_flags"]


class SceneFlags:
    """Per class, per scene: the scores and true-positive flags of its predictions (in the scene's file
    order) and its number of ground-truth objects, at one distance threshold."""

    def __init__(self, classes, scenes, scores, is_tp, n_gt):
        self.classes, self.scenes = list(classes), list(scenes)
        self.scores, self.is_tp, self.n_gt = scores, is_tp, n_gt

    def map(self, counts: np.ndarray, min_recall: float, min_precision: float) -> float:
        """mAP (mean over classes of AP) of the multiset of scenes with `counts[s]` copies of scene s."""
        aps = []
        for c in range(len(self.classes)):
            take = np.repeat(np.arange(len(self.scenes)), counts)
            n_gt = int(np.dot(counts, self.n_gt[c]))
            sc = np.concatenate([self.scores[c][s] for s in take]) if len(take) else np.zeros(0)
            tp = np.concatenate([self.is_tp[c][s] for s in take]) if len(take) else np.zeros(0, bool)
            order = ranking_order(sc)  # the devkit's ranking of the pooled predictions, ties included
            _, prec, _ = interpolated_pr(tp[order], sc[order], n_gt)
            aps.append(average_precision(prec, min_recall, min_precision))
        return float(np.mean(aps))


def scene_flags(gt: dict, dets: dict, classes, scenes, dist_th_m: float) -> SceneFlags:
    """The per-scene matching of one method (gt / dets: scene -> objects / detections, already filtered
    to what is evaluated) at threshold dist_th_m (m)."""
    scores, is_tp, n_gt = [], [], []
    for cls in classes:
        sc_c, tp_c, n_c = [], [], []
        for sid in scenes:
            pooled = pool_class(gt, dets, cls, [sid])
            m = match_class(pooled, dist_th_m)
            tp = np.zeros(len(m.order), dtype=bool)
            tp[m.order] = m.is_tp  # back to the scene's file order, as evaluate pools them
            counted = np.ones(len(m.order), dtype=bool)
            counted[m.order] = ~m.is_ignored  # predictions on don't-care objects count for nothing
            sc_c.append(pooled.pred_scores[counted])
            tp_c.append(tp[counted])
            n_c.append(m.n_gt)
        scores.append(sc_c)
        is_tp.append(tp_c)
        n_gt.append(np.asarray(n_c, dtype=np.int64))
    return SceneFlags(classes, scenes, scores, is_tp, np.asarray(n_gt))


def bootstrap_map(flags: dict[str, SceneFlags], n_resamples: int = 1000, seed: int = 0, min_recall: float = 0.1,
                  min_precision: float = 0.1) -> dict[str, np.ndarray]:
    """mAP of each method (name -> SceneFlags over the same scenes) on `n_resamples` paired resamples
    of the scenes (multinomial counts drawn once per resample, shared by every method). Returns
    method -> (n_resamples,) array."""
    scenes = {tuple(f.scenes) for f in flags.values()}
    if len(scenes) != 1:
        raise ValueError("bootstrap_map: every method must be matched on the same scenes, in the same order")
    n = len(next(iter(scenes)))
    if n == 0:
        raise ValueError("bootstrap_map: no scenes")
    rng = np.random.default_rng(seed)
    counts = rng.multinomial(n, np.full(n, 1.0 / n), size=int(n_resamples))
    return {m: np.array([f.map(c, min_recall, min_precision) for c in counts]) for m, f in flags.items()}


def interval(samples: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """Percentile interval (low, high) holding `level` of the bootstrap samples."""
    a = (1.0 - level) / 2.0
    lo, hi = np.quantile(np.asarray(samples, dtype=np.float64), [a, 1.0 - a])
    return float(lo), float(hi)
