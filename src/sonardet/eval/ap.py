"""Precision/recall curves, average precision and recall-averaged true-positive errors.

A re-implementation of nuscenes-devkit's `accumulate` (curve part), `calc_ap` and `calc_tp`
(`nuscenes/eval/detection/algo.py`, devkit 1.2.0) with the same numpy calls in the same order, so
the results agree bit for bit (tests/test_eval_devkit_peer.py checks this against the devkit itself):

- precision and recall of the score-sorted predictions are interpolated onto a 101-point recall grid
  0, 0.01, ..., 1 with `np.interp(grid, recall, precision, right=0)` (recall may repeat; np.interp then
  takes the value of the last prediction with that recall);
- AP = mean over grid points with index > round(100 * min_recall) of max(precision - min_precision, 0),
  divided by (1 - min_precision);
- a class without matches gets the devkit's "no predictions" curve: precision and confidence all 0.
"""

from __future__ import annotations

import numpy as np

#: Number of recall grid points (the devkit's DetectionMetricData.nelem).
N_RECALL_POINTS = 101


def recall_grid() -> np.ndarray:
    """The 101 recall values 0, 0.01, ..., 1 on which curves are interpolated."""
    return np.linspace(0.0, 1.0, N_RECALL_POINTS)


def _check_min(min_recall: float, min_precision: float) -> None:
    if not 0.0 <= min_precision < 1.0:
        raise ValueError(f"min_precision must be in [0, 1), got {min_precision}")
    if not 0.0 <= min_recall <= 1.0:
        raise ValueError(f"min_recall must be in [0, 1], got {min_recall}")


def first_recall_index(min_recall: float) -> int:
    """Index of the first recall grid point used by AP and TP errors: round(100 * min_recall) + 1.

    Python's `round` (half to even) on the float product, exactly as the devkit does; the +1 leaves out
    the min_recall point itself.
    """
    return round(100 * min_recall) + 1


def interpolated_pr(is_tp, scores_sorted, n_gt: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interpolated (recall, precision, confidence) curves, each (101,), of one class at one threshold.

    is_tp: (N,) bool, whether each prediction (sorted by score, descending, in matching order) matched.
    scores_sorted: (N,) the scores in the same order. n_gt: number of ground-truth objects of the class.
    With no ground truth or no true positive, returns the devkit's "no predictions" curves
    (precision = confidence = 0 everywhere).
    """
    grid = recall_grid()
    is_tp = np.asarray(is_tp, dtype=bool)
    if n_gt == 0 or not is_tp.any():
        return grid, np.zeros(N_RECALL_POINTS), np.zeros(N_RECALL_POINTS)
    tp = np.cumsum(is_tp.astype(np.int64)).astype(float)
    fp = np.cumsum((~is_tp).astype(np.int64)).astype(float)
    conf = np.asarray(scores_sorted, dtype=np.float64)
    prec = tp / (fp + tp)
    rec = tp / float(n_gt)
    prec_i = np.interp(grid, rec, prec, right=0)
    conf_i = np.interp(grid, rec, conf, right=0)
    return grid, prec_i, conf_i


def average_precision(precision, min_recall: float = 0.1, min_precision: float = 0.1) -> float:
    """nuScenes AP (unitless, [0, 1]) from the interpolated precision (101,) (devkit `calc_ap`).

    Precision at recall grid indices above round(100 * min_recall) is reduced by min_precision, clipped at
    0, averaged and divided by (1 - min_precision), so a detector that never beats min_precision scores 0
    and a perfect one scores 1.
    """
    _check_min(min_recall, min_precision)
    prec = np.array(precision, dtype=np.float64, copy=True)
    prec = prec[first_recall_index(min_recall):]
    prec -= min_precision
    prec[prec < 0] = 0
    return float(np.mean(prec)) / (1.0 - min_precision)


def cumulative_mean(x) -> np.ndarray:
    """Running mean of x (N,) ignoring NaNs; all ones if every value is NaN (devkit `cummean`)."""
    x = np.asarray(x, dtype=np.float64)
    if np.isnan(x).sum() == len(x):
        return np.ones(len(x))
    sums = np.nancumsum(x)
    counts = np.cumsum(~np.isnan(x))
    return np.divide(sums, counts, out=np.zeros_like(sums), where=counts != 0)


def interpolated_tp_error(errors, match_scores, confidence) -> np.ndarray:
    """A TP error (one value per match, in matching order) resampled onto the recall grid (101,).

    The running mean of the errors is interpolated against the matches' scores at the curve's
    interpolated confidence (devkit `accumulate`, match-data resampling).
    """
    tmp = cumulative_mean(errors)
    conf = np.asarray(confidence, dtype=np.float64)
    ms = np.asarray(match_scores, dtype=np.float64)
    return np.interp(conf[::-1], ms[::-1], tmp[::-1])[::-1]


def max_recall_index(confidence) -> int:
    """Index on the recall grid of the highest recall reached: the last non-zero interpolated confidence."""
    nz = np.nonzero(np.asarray(confidence))[0]
    return int(nz[-1]) if len(nz) else 0


def recall_averaged_tp_error(error_curve, confidence, min_recall: float = 0.1) -> float:
    """Mean of a TP-error curve (101,) over recall grid indices round(100*min_recall)+1 .. max recall.

    Same as devkit `calc_tp`, including its convention of returning 1.0 when the class never reaches a
    recall above min_recall (callers flag that case; `evaluate` reports None when there is no TP at all).
    """
    first = first_recall_index(min_recall)
    last = max_recall_index(confidence)
    if last < first:
        return 1.0
    return float(np.mean(np.asarray(error_curve)[first:last + 1]))
