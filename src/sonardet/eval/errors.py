"""True-positive error metrics between a matched ground-truth box and a predicted box.

Boxes are `[x, y, z, l, w, h, yaw]` in the scene frame (metres, radians; DESIGN.md section 2). The
definitions and the floating-point order of operations follow nuscenes-devkit
(`nuscenes/eval/common/utils.py`: `center_distance`, `scale_iou`, `yaw_diff`), so the values agree
with the devkit bit for bit (centre, size) or to a few ulp (yaw, which the devkit recovers from a
quaternion).
"""

from __future__ import annotations

import numpy as np


def center_distance_matrix(pred_xy, gt_xy) -> np.ndarray:
    """2D centre distances (m) between every prediction (P,2) and every ground truth (G,2): (P,G).

    Each entry is `sqrt(d . d)` with `d` the (x, y) difference, computed with a 1-D dot product per pair
    (numpy routes `1xn @ nx1` matmuls to BLAS `ddot`). That is the floating-point path of the devkit's
    `np.linalg.norm(pred[:2] - gt[:2])`; `sqrt(dx*dx + dy*dy)` differs from it in the last bit for about
    8 % of pairs (BLAS uses fused multiply-add), which would flip matches lying exactly at a threshold.
    """
    p = np.asarray(pred_xy, dtype=np.float64).reshape(-1, 2)
    g = np.asarray(gt_xy, dtype=np.float64).reshape(-1, 2)
    d = p[:, None, :] - g[None, :, :]  # (P, G, 2)
    if d.size == 0:
        return np.zeros((len(p), len(g)))
    sq = np.matmul(d[..., None, :], d[..., :, None])[..., 0, 0]
    return np.sqrt(sq)


def center_error_m(gt_box, pred_box) -> float:
    """2D distance (m) between the (x, y) centres of two boxes `[x,y,z,l,w,h,yaw]` (z is ignored)."""
    d = np.asarray(pred_box, dtype=np.float64)[:2] - np.asarray(gt_box, dtype=np.float64)[:2]
    return float(np.sqrt(d.dot(d)))


def scale_iou(gt_box, pred_box) -> float:
    """3D IoU (unitless, [0, 1]) of two boxes after aligning their centres and yaw: only l, w, h count.

    Extents must be >= 0 (m). When both boxes have zero volume the IoU is 1 for identical extents and
    0 otherwise (the devkit asserts positive extents instead).
    """
    g = np.asarray(gt_box, dtype=np.float64)
    p = np.asarray(pred_box, dtype=np.float64)
    # The devkit stores sizes as (w, l, h); keep its product order so the values agree bitwise.
    g_wlh = np.array([g[4], g[3], g[5]])
    p_wlh = np.array([p[4], p[3], p[5]])
    if np.any(g_wlh < 0) or np.any(p_wlh < 0):
        raise ValueError(f"box extents must be >= 0, got {g_wlh.tolist()} and {p_wlh.tolist()} (w, l, h)")
    inter = np.prod(np.minimum(g_wlh, p_wlh))
    union = np.prod(g_wlh) + np.prod(p_wlh) - inter
    if union <= 0.0:
        return 1.0 if np.array_equal(g_wlh, p_wlh) else 0.0
    return float(inter / union)


def size_error(gt_box, pred_box) -> float:
    """Size error (unitless, [0, 1]): `1 - scale_iou`, i.e. 1 - IoU after aligning centres and yaw."""
    return 1.0 - scale_iou(gt_box, pred_box)


def angle_diff_rad(x_rad: float, y_rad: float, period_rad: float = 2.0 * np.pi) -> float:
    """Signed smallest difference x - y (rad) of two angles with the given periodicity, in (-pi, pi]."""
    diff = (float(x_rad) - float(y_rad) + period_rad / 2.0) % period_rad - period_rad / 2.0
    if diff > np.pi:
        diff -= 2.0 * np.pi
    return diff


def yaw_error_rad(gt_yaw_rad: float, pred_yaw_rad: float, period_rad: float = 2.0 * np.pi) -> float:
    """Absolute smallest yaw difference (rad, [0, pi]) between a ground-truth and a predicted heading.

    `period_rad` is the angle after which the shape repeats (2 pi for an asymmetric box; the devkit uses
    pi for barriers). Rotationally symmetric classes are not scored at all (see `evaluate`).
    """
    return abs(angle_diff_rad(gt_yaw_rad, pred_yaw_rad, period_rad))
