"""Boxes, rotations and point-in-box tests shared by every stage."""

from .boxes import box_corners, box_from_points, box_of_posed_vertices, points_in_box
from .rotations import (
    matrix_to_quat,
    quat_from_yaw,
    quat_multiply,
    quat_normalize,
    quat_to_matrix,
    random_quat,
    transform_points,
    wrap_angle,
    yaw_of_matrix,
)

__all__ = [
    "box_corners",
    "box_from_points",
    "box_of_posed_vertices",
    "points_in_box",
    "matrix_to_quat",
    "quat_from_yaw",
    "quat_multiply",
    "quat_normalize",
    "quat_to_matrix",
    "random_quat",
    "transform_points",
    "wrap_angle",
    "yaw_of_matrix",
]
