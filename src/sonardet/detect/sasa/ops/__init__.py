"""Point operators of the SASA detector in vectorised PyTorch (CPU and CUDA), FPS and the ball query
with compiled CPU kernels.

* :mod:`.sampling`: D-FPS, weighted FPS and S-FPS (reference ``furthest_point_sample*`` kernels).
* :mod:`.grouping`: ball query (plain, dilated, multi-radius), gather/grouping, QueryAndGroup.
* :mod:`.rotated_iou`: exact rotated BEV / 3-D IoU and greedy rotated-BEV NMS.
* :mod:`.kernels`: Numba kernels that FPS and the ball query use on CPU (same indices as the
  PyTorch paths, which remain for CUDA and as the fallback).

Every function follows the device of its input tensors. Index outputs are int64.
"""

from .grouping import (
    GroupAll,
    QueryAndGroup,
    ball_query,
    ball_query_dilated,
    ball_query_shells,
    gather_operation,
    group_with_idx,
    grouping_operation,
    index_points,
)
from .rotated_iou import bev_corners, iou3d_rotated, iou_bev_rotated, nms_bev_rotated, overlap_bev_rotated
from .sampling import (
    fps_block_size,
    furthest_point_sample,
    semantic_furthest_point_sample,
    weighted_furthest_point_sample,
)

__all__ = [
    "GroupAll",
    "QueryAndGroup",
    "ball_query",
    "ball_query_dilated",
    "ball_query_shells",
    "bev_corners",
    "fps_block_size",
    "furthest_point_sample",
    "gather_operation",
    "group_with_idx",
    "grouping_operation",
    "index_points",
    "iou3d_rotated",
    "iou_bev_rotated",
    "nms_bev_rotated",
    "overlap_bev_rotated",
    "semantic_furthest_point_sample",
    "weighted_furthest_point_sample",
]
