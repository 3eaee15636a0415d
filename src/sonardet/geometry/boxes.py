"""Gravity-aligned 3D boxes `[x, y, z, l, w, h, yaw]` (DESIGN.md section 2).

(x, y, z) is the box centre in metres, (l, w, h) its extents in metres with `l` along the yaw
direction, `w` across it and `h` vertical; yaw (rad, [-pi, pi)) turns the box about +z.
"""

from __future__ import annotations

import numpy as np

from .rotations import quat_to_matrix, wrap_angle, yaw_of_matrix


def box_from_points(points, yaw_rad: float) -> np.ndarray:
    """Smallest box with the given yaw that encloses points (N,3) (scene frame, metres)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"points must be a non-empty (N,3) array, got shape {p.shape}")
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    # Coordinates in the yaw-rotated frame: u along yaw, v across.
    u = p[:, 0] * c + p[:, 1] * s
    v = -p[:, 0] * s + p[:, 1] * c
    umin, umax, vmin, vmax = u.min(), u.max(), v.min(), v.max()
    zmin, zmax = p[:, 2].min(), p[:, 2].max()
    uc, vc = 0.5 * (umin + umax), 0.5 * (vmin + vmax)
    return np.array(
        [uc * c - vc * s, uc * s + vc * c, 0.5 * (zmin + zmax), umax - umin, vmax - vmin, zmax - zmin,
         float(wrap_angle(yaw_rad))]
    )


def box_of_posed_vertices(canonical_vertices, t, q) -> np.ndarray:
    """Evaluation box of a mesh (canonical vertices (N,3)) placed at pose (t, q=(w,x,y,z)).

    The yaw is the heading of the canonical +x axis after the rotation; the box is the smallest
    gravity-aligned box with that yaw enclosing the posed vertices.
    """
    r = quat_to_matrix(q)
    posed = np.asarray(canonical_vertices, dtype=np.float64) @ r.T + np.asarray(t, dtype=np.float64)
    return box_from_points(posed, yaw_of_matrix(r))


def box_corners(box) -> np.ndarray:
    """The 8 corners (8,3) of a box `[x,y,z,l,w,h,yaw]`; bottom four first, counter-clockwise."""
    x, y, z, l, w, h, yaw = np.asarray(box, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    du = np.array([0.5, -0.5, -0.5, 0.5]) * l
    dv = np.array([0.5, 0.5, -0.5, -0.5]) * w
    xs = x + du * c - dv * s
    ys = y + du * s + dv * c
    bottom = np.stack([xs, ys, np.full(4, z - 0.5 * h)], 1)
    top = np.stack([xs, ys, np.full(4, z + 0.5 * h)], 1)
    return np.vstack([bottom, top])


def points_in_box(points, box, margin_m: float = 0.0) -> np.ndarray:
    """Boolean mask (N,) of points (N,3) inside box `[x,y,z,l,w,h,yaw]` grown by margin_m on every side."""
    p = np.asarray(points, dtype=np.float64)
    x, y, z, l, w, h, yaw = np.asarray(box, dtype=np.float64)
    dx, dy = p[:, 0] - x, p[:, 1] - y
    c, s = np.cos(yaw), np.sin(yaw)
    u = dx * c + dy * s
    v = -dx * s + dy * c
    return (
        (np.abs(u) <= 0.5 * l + margin_m)
        & (np.abs(v) <= 0.5 * w + margin_m)
        & (np.abs(p[:, 2] - z) <= 0.5 * h + margin_m)
    )
