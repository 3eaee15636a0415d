"""nuScenes-style matching and AP, and true-positive error metrics (checked against nuscenes-devkit)."""

from .ap import average_precision, interpolated_pr, recall_averaged_tp_error, recall_grid
from .errors import center_distance_matrix, center_error_m, scale_iou, size_error, yaw_error_rad
from .evaluate import evaluate, evaluate_files, metrics_for_json, threshold_key
from .matching import match_class, pool_class, ranking_order

__all__ = [
    "average_precision",
    "center_distance_matrix",
    "center_error_m",
    "evaluate",
    "evaluate_files",
    "interpolated_pr",
    "match_class",
    "metrics_for_json",
    "pool_class",
    "ranking_order",
    "recall_averaged_tp_error",
    "recall_grid",
    "scale_iou",
    "size_error",
    "threshold_key",
    "yaw_error_rad",
]
