"""Scene preparation for SASA: ground filter, local frame, fixed-size sampling, augmentation, batching.

A scene (``scenes/{id}.npz`` + ``scenes/{id}.json``) becomes a :class:`PreparedScene`:

1. ground estimate: minimum z per ``ground_cell_m`` cell (empty cells take the nearest filled one),
   bilinearly interpolated between cell centres (:func:`ground_height`);
2. with ``ground_filter``, only points higher than ``ground_height_m`` above it are kept ("model only
   what the scene needs": ~45k of ~300k points remain, see config.py);
3. local frame: subtract ``origin`` = (centre of the xy bounding box of all points, median ground z),
   in float64, then cast to float32; boxes are shifted the same way; outputs are shifted back;
4. per-point feature: height above the ground estimate (m).

:func:`sample_points` draws the fixed ``n_points`` (without replacement; a scene with fewer points is
padded by resampling with a warning). :func:`augment` applies the training augmentation in numpy.
With ``dr_enabled``, training scenes go through :func:`domain_randomise` instead of
:func:`sample_points`: randomised sensor effects on the kept points (the ground grid of step 1 is kept
in ``PreparedScene.meta["ground_grid"]`` for it), then a weighted sample (see config.py).
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from ...io.annotations import read_scene
from ...sim.effects.attitude import heave_dz, roll_bias_dz, sinusoid
from ...sim.effects.burial import burial_depths, burial_dz
from ...sim.effects.line_offsets import line_offset_dz, line_offsets_m
from ...sim.effects.noise import range_noise_dz
from ...sim.effects.outliers import draw_spikes
from ...sim.effects.refraction import flat_seabed_cos, svp_bias_dz
from ...sim.effects.roughness import roughness_point_offsets
from ...io.artifacts import read_json_file
from ...io.scenes import read_scene_points
from ...jit import numba

log = logging.getLogger(__name__)

__all__ = ["PreparedScene", "ground_grid", "ground_at", "ground_height", "prepare_points", "prepare_scene",
           "scene_paths", "sample_points", "augment", "canonicalize_boxes", "collate", "PaddingWarning", "wrap_yaw",
           "DomainRandomised", "domain_randomise", "dr_z_field", "dr_density_weight", "weighted_sample"]


class PaddingWarning(UserWarning):
    """A scene had fewer (kept) points than ``n_points`` and was padded by resampling."""


@dataclass
class PreparedScene:
    """One scene in the local frame (float32 unless noted).

    xyz: (N, 3) kept points (m, local frame); height: (N,) height above the ground estimate (m);
    label: (N,) int64 object id of the point or -1; boxes: (K, 7) ``[x, y, z, l, w, h, yaw]`` (m, rad,
    local frame); cls: (K,) int64 class index; obj_id: (K,) object ids; origin: (3,) float64 offset
    (local = scene - origin); scene_id: str; n_raw: points before the ground filter; axis: (K, 3) a
    point on each object's vertical symmetry axis (its pose translation, local frame), used to turn
    the boxes of n-fold symmetric objects correctly in augmentation (default: the box centres).
    """

    scene_id: str
    xyz: np.ndarray
    height: np.ndarray
    label: np.ndarray
    boxes: np.ndarray
    cls: np.ndarray
    obj_id: np.ndarray
    origin: np.ndarray
    n_raw: int
    axis: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.axis is None:  # no poses known: the box centres stand in for the symmetry axes
            self.axis = self.boxes[:, :3].copy()


def wrap_yaw(yaw, period: float = 2 * math.pi):
    """Wrap angles (rad) into [-period/2, period/2)."""
    return (np.asarray(yaw) + 0.5 * period) % period - 0.5 * period


def ground_grid(xyz: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The grid-minimum ground estimate: (lo (2,) float64 x, y of the grid corner (m), grid (nx, ny)
    float64 minimum z per ``cell_m`` cell, empty cells filled from the nearest filled one)."""
    xy = xyz[:, :2].astype(np.float64)
    lo = xy.min(axis=0)
    ij = np.floor((xy - lo) / cell_m).astype(np.int64)
    nx, ny = (ij.max(axis=0) + 1).tolist()
    grid = np.full((nx, ny), np.inf)
    np.minimum.at(grid, (ij[:, 0], ij[:, 1]), xyz[:, 2].astype(np.float64))
    empty = ~np.isfinite(grid)
    if empty.any():
        _, idx = ndimage.distance_transform_edt(empty, return_distances=True, return_indices=True)
        grid = grid[tuple(idx)]
    return lo, grid


def ground_at(lo: np.ndarray, grid: np.ndarray, cell_m: float, xy: np.ndarray) -> np.ndarray:
    """Ground z (m, (n,) float64) at points xy (n, 2) of a :func:`ground_grid` (bilinear between cell centres)."""
    u = (np.asarray(xy, dtype=np.float64) - lo) / cell_m - 0.5  # cell-centre coordinates
    return ndimage.map_coordinates(grid, [u[:, 0], u[:, 1]], order=1, mode="nearest")


def ground_height(xyz: np.ndarray, cell_m: float) -> np.ndarray:
    """Ground elevation (m) under each point (N,) from the grid minimum (cell ``cell_m``, bilinear).

    Args:
        xyz: (N, 3) float array (m), N >= 1.
        cell_m: cell size (m).
    Returns:
        (N,) float64 ground z at every point's (x, y).
    """
    lo, grid = ground_grid(xyz, cell_m)
    return ground_at(lo, grid, cell_m, xyz[:, :2].astype(np.float64))


def prepare_points(xyz: np.ndarray, params: dict, origin: np.ndarray | None = None):
    """Ground filter + local frame for a raw cloud (N, 3) float64 (scene frame, m).

    Returns (keep (N,) bool, local xyz (M, 3) float32, height (M,) float32, origin (3,) float64).
    """
    keep, local, h, origin, _ = _prepare_points(xyz, params, origin)
    return keep, local, h, origin


def _prepare_points(xyz: np.ndarray, params: dict, origin: np.ndarray | None = None):
    """:func:`prepare_points` plus the ground grid in the local frame ({"lo", "z", "cell_m"})."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or len(xyz) == 0:
        raise ValueError(f"points must be a non-empty (N, 3) array, got shape {xyz.shape}")
    cell = float(params["ground_cell_m"])
    lo, grid = ground_grid(xyz, cell)
    ground = ground_at(lo, grid, cell, xyz[:, :2].astype(np.float64))
    h = xyz[:, 2] - ground
    if params["ground_filter"]:
        keep = h > float(params["ground_height_m"])
        if not keep.any():  # a flat, empty scene: keep everything rather than nothing
            keep = np.ones(len(xyz), dtype=bool)
    else:
        keep = np.ones(len(xyz), dtype=bool)
    if origin is None:
        lo, hi = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
        origin = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), float(np.median(ground))])
    local = (xyz[keep] - origin).astype(np.float32)
    gg = {"lo": lo - origin[:2], "hi": xyz[:, :2].max(axis=0) - origin[:2], "z": grid - origin[2], "cell_m": cell}
    return keep, local, h[keep].astype(np.float32), origin, gg


def scene_paths(path) -> tuple[Path, Path]:
    """(npz, json) paths of a scene given either file (or the stem)."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".npz", ".json") else p
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


def prepare_scene(path, params: dict, with_labels: bool = True) -> PreparedScene:
    """Load a scene (npz [+ json]) and prepare it (see module docstring). Labels need the json."""
    npz, js = scene_paths(path)
    pts = read_scene_points(npz)
    keep, local, height, origin, gg = _prepare_points(pts["xyz"], params)
    classes = list(params["classes"])
    label = pts.get("label")
    label = np.full(len(local), -1, np.int64) if label is None else np.asarray(label, np.int64)[keep]
    boxes = np.zeros((0, 7), np.float32)
    axis = np.zeros((0, 3), np.float32)
    cls = np.zeros(0, np.int64)
    obj_id = np.zeros(0, np.int64)
    meta = {}
    if with_labels and js.exists():
        doc = read_scene(js, classes=None)
        objs = [o for o in doc["objects"] if o["cls"] in classes]
        if objs:
            b = np.array([o["box"] for o in objs], dtype=np.float64)
            b[:, :3] -= origin
            boxes = b.astype(np.float32)
            axis = (np.array([o["pose"]["t"] for o in objs], dtype=np.float64) - origin).astype(np.float32)
            cls = np.array([classes.index(o["cls"]) for o in objs], np.int64)
            obj_id = np.array([o["id"] for o in objs], np.int64)
        meta = {"n_objects": len(objs)}
    meta["ground_grid"] = gg  # the ground estimate (local frame), used by domain_randomise
    sid = npz.stem
    return PreparedScene(sid, local, height, label, boxes, cls, obj_id, origin, int(len(pts["xyz"])), axis, meta)


def sample_points(n_have: int, n_points: int, rng: np.random.Generator, scene_id: str = "?") -> np.ndarray:
    """Indices of a fixed-size sample: ``n_points`` of ``n_have`` without replacement, shuffled.

    With fewer points than ``n_points`` every point is used once and the rest is drawn with
    replacement (a :class:`PaddingWarning` names the scene). Returns (n_points,) int64.
    """
    if n_have <= 0:
        raise ValueError(f"scene {scene_id}: no points to sample from")
    if n_have >= n_points:
        return rng.choice(n_have, n_points, replace=False).astype(np.int64)
    warnings.warn(f"scene {scene_id}: only {n_have} points (after the ground filter) for n_points={n_points}; "
                  f"padding by resampling {n_points - n_have} of them", PaddingWarning, stacklevel=2)
    idx = np.concatenate([np.arange(n_have), rng.choice(n_have, n_points - n_have, replace=True)])
    return rng.permutation(idx).astype(np.int64)


def _rot2(v: np.ndarray, ang) -> np.ndarray:
    """Rotate 2-D vectors (n, 2) by angles (n,) or a scalar (rad)."""
    c, s = np.cos(ang), np.sin(ang)
    return np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]], axis=1)


def canonicalize_boxes(boxes: np.ndarray, axis: np.ndarray, cls: np.ndarray, sym: np.ndarray,
                       turned: np.ndarray) -> None:
    """Bring boxes that were turned (mirrored, rotated) back to the scene-box convention, in place.

    boxes: (K, 7) the exact transform of the original boxes (centre moved, yaw turned); axis: (K, 3)
    the transformed symmetry-axis points; turned: (K,) the yaw change applied (rad); sym[c]: symmetry
    order of class c.

    * order k >= 1: yaw is wrapped into [-pi/k, pi/k) (scene convention); the box of the *same*
      object at the wrapped yaw is the current box turned about the object's symmetry axis by the
      wrap amount (exact for an object that is k-fold symmetric about a vertical axis: a tetrapod's
      box centre lies 0.2-0.9 m off its axis, so turning about the box centre would be wrong);
    * order 0 (rotationally symmetric): the box stays axis aligned with yaw 0; a near-square footprint
      keeps its extents, an elongated one (a ring on its edge) takes the bounding rectangle of the
      turned box; the centre keeps its transformed position.
    """
    order = sym[cls]
    free = order == 0
    if free.any():
        l, w = boxes[free, 3].copy(), boxes[free, 4].copy()
        c, s = np.abs(np.cos(turned[free])), np.abs(np.sin(turned[free]))
        elong = np.abs(l - w) > 0.1 * np.maximum(l, w)
        boxes[free, 3] = np.where(elong, l * c + w * s, l)
        boxes[free, 4] = np.where(elong, l * s + w * c, w)
        boxes[free, 6] = 0.0
    k = ~free
    if k.any():
        period = 2 * math.pi / order[k]
        raw = boxes[k, 6].astype(np.float64)
        final = wrap_yaw(raw, period)
        delta = final - raw
        boxes[k, :2] = axis[k, :2] + _rot2(boxes[k, :2] - axis[k, :2], delta)
        boxes[k, 6] = final


def augment(xyz: np.ndarray, height: np.ndarray, label: np.ndarray, boxes: np.ndarray, cls: np.ndarray,
            obj_id: np.ndarray, params: dict, rng: np.random.Generator, axis: np.ndarray | None = None):
    """Training augmentation on one sampled scene (copies; local frame, m, rad).

    Order: per-object jitter (the points with the object's label turn about its symmetry axis and
    move with its box), flips, world rotation about z, world scaling (points, box centres and sizes,
    and the height feature). After every turn the boxes are canonicalised
    (:func:`canonicalize_boxes`), so they match what the simulator would label.
    Args: xyz (N, 3), height (N,), label (N,) object id or -1, boxes (K, 7), cls (K,), obj_id (K,),
    axis (K, 3) symmetry-axis points (default: box centres).
    Returns (xyz, height, boxes) augmented.
    """
    xyz = xyz.astype(np.float32, copy=True)
    height = height.astype(np.float32, copy=True)
    boxes = boxes.astype(np.float64, copy=True)
    axis = (boxes[:, :3].copy() if axis is None else np.asarray(axis, np.float64).copy())
    sym = np.array([int(params["symmetry_orders"][c]) for c in params["classes"]], np.int64)
    K = len(boxes)
    # 1. per-object jitter
    p_obj = float(params["aug_object_prob"])
    if K and p_obj > 0:
        radius = 0.5 * np.hypot(boxes[:, 3], boxes[:, 4])
        for k in range(K):
            if rng.random() >= p_obj:
                continue
            shift = rng.normal(0.0, float(params["aug_object_sigma_m"]), 2)
            ang = rng.uniform(-1, 1) * float(params["aug_object_rotation_rad"])
            new_c = boxes[k, :2] + shift
            others = np.arange(K) != k
            if others.any():
                d_old = np.hypot(*(boxes[others, :2] - boxes[k, :2]).T)
                d_new = np.hypot(*(boxes[others, :2] - new_c).T)
                clear = d_new >= radius[others] + radius[k]
                if not np.all(clear | (d_new >= d_old)):
                    continue  # would push into a neighbour: skip this object
            a = axis[k, :2].copy()
            m = label == obj_id[k]
            if m.any():
                xyz[m, :2] = (a + _rot2(xyz[m, :2].astype(np.float64) - a, ang) + shift).astype(np.float32)
            boxes[k, :2] = a + _rot2(boxes[k:k + 1, :2] - a, ang)[0] + shift
            boxes[k, 6] += ang
            axis[k, :2] = a + shift
            canonicalize_boxes(boxes[k:k + 1], axis[k:k + 1], cls[k:k + 1], sym, np.array([ang]))
    # 2. flips (a mirrored box at yaw phi equals the box at phi + pi)
    if params["aug_flip_x"] and rng.random() < 0.5:  # mirror across the x axis: y -> -y, yaw -> -yaw
        xyz[:, 1] *= -1
        boxes[:, 1] *= -1
        axis[:, 1] *= -1
        boxes[:, 6] *= -1
        canonicalize_boxes(boxes, axis, cls, sym, np.zeros(K))
    if params["aug_flip_y"] and rng.random() < 0.5:  # mirror across the y axis: x -> -x, yaw -> pi - yaw
        xyz[:, 0] *= -1
        boxes[:, 0] *= -1
        axis[:, 0] *= -1
        boxes[:, 6] = math.pi - boxes[:, 6]
        canonicalize_boxes(boxes, axis, cls, sym, np.zeros(K))
    # 3. world rotation
    a = float(params["aug_rotation_rad"])
    if a > 0:
        ang = rng.uniform(-a, a)
        xyz[:, :2] = _rot2(xyz[:, :2].astype(np.float64), ang).astype(np.float32)
        if K:
            boxes[:, :2] = _rot2(boxes[:, :2], ang)
            axis[:, :2] = _rot2(axis[:, :2], ang)
            boxes[:, 6] += ang
            canonicalize_boxes(boxes, axis, cls, sym, np.full(K, ang))
    # 4. world scaling
    lo, hi = params["aug_scale"]
    if hi > lo or lo != 1.0:
        f = rng.uniform(lo, hi)
        xyz *= f
        height *= f
        boxes[:, :6] *= f
    return xyz, height, boxes.astype(np.float32)


# ---------------------------------------------------------------------------------------------------
# Domain randomisation (training only; the ranges and their reasoning are in config.py's docstring)
# ---------------------------------------------------------------------------------------------------

#: One random stream per effect (children of one draw per scene): changing one effect's range leaves
#: the realisation of every other effect unchanged.
DR_STREAMS = ("burial", "outliers", "leak", "density", "dropout", "sample", "zfield", "lines", "noise",
              "roughness", "shape")
#: Neighbours (of the same object) whose PCA gives a point's normal in the shape effect.
DR_SHAPE_NEIGHBOURS = 8
#: Normals flatter than this (|n_z|) get the fouling shell only: which side is outside is unknown.
DR_SHAPE_MIN_NZ = 0.2
#: Half the swath angle (deg; a 130 deg swath): the smile is flat beyond the swath edge.
DR_HALF_SWATH_DEG = 65.0
#: Number and wavelength range (m) of the waves of the smooth sampling-density field.
DR_DENSITY_WAVES = 3
DR_DENSITY_WAVELENGTH_M = (8.0, 40.0)
#: Largest aspect ratio (semi-major / semi-minor axis) of a dropout ellipse.
DR_BLOB_ASPECT = 3.0
#: Generated points (spikes, leaked seabed) stay out of the gt box footprints grown by this (m, per side).
DR_BOX_MARGIN_M = 0.2
#: An object rests on the seabed (and may be sunk) if its box bottom is at most this above the ground (m).
DR_REST_TOL_M = 0.3


@dataclass
class DomainRandomised:
    """One randomised, sampled training scene (local frame).

    xyz (n_points, 3) float32, height (n_points,) float32, label (n_points,) int64 (object id or -1),
    boxes (K, 7) float32, axis (K, 3) float32 (the scene's boxes/axes moved with their points),
    source (n_points,) int64: index of the scene point each point came from, -1 for a leaked seabed
    point, -2 for a spike; draws: the per-scene values drawn (for tests and diagnostics).
    """

    xyz: np.ndarray
    height: np.ndarray
    label: np.ndarray
    boxes: np.ndarray
    axis: np.ndarray
    source: np.ndarray
    draws: dict


def _draw(rng: np.random.Generator, rng_range) -> float:
    """One value U(low, high) (one draw, also for low == high)."""
    return float(rng.uniform(float(rng_range[0]), float(rng_range[1])))


def _draw_int(rng: np.random.Generator, rng_range) -> int:
    """One integer uniform in [low, high] (both included)."""
    return int(rng.integers(int(rng_range[0]), int(rng_range[1]) + 1))


def _ground_model(scene: PreparedScene, cell_m: float):
    """The ground estimate of a scene in the local frame: (ground z at xy (n, 2) -> (n,), footprint low
    (2,), footprint high (2,), grid corner (2,), grid shape (nx, ny)). From the scene's ground grid
    (:func:`prepare_scene` stores it) or, without one, a plane through the ground z (= z - height) of
    the kept points on a grid of ``cell_m`` cells over their footprint."""
    gg = scene.meta.get("ground_grid") if scene.meta else None
    if gg is not None:
        lo, grid, cell = np.asarray(gg["lo"], np.float64), np.asarray(gg["z"], np.float64), float(gg["cell_m"])
        hi = np.asarray(gg.get("hi", lo + np.array(grid.shape) * cell), np.float64)
        return (lambda q: ground_at(lo, grid, cell, q)), lo, hi, lo, grid.shape
    xy = scene.xyz[:, :2].astype(np.float64)
    gz = scene.xyz[:, 2].astype(np.float64) - scene.height.astype(np.float64)
    coef = np.linalg.lstsq(np.c_[np.ones(len(xy)), xy], gz, rcond=None)[0]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    shape = tuple(int(v) for v in np.floor((hi - lo) / cell_m).astype(np.int64) + 1)
    return (lambda q: coef[0] + np.asarray(q, np.float64) @ coef[1:]), lo, hi, lo, shape


def _in_box_footprints(xy: np.ndarray, boxes: np.ndarray, margin_m: float) -> np.ndarray:
    """(n,) bool: xy (n, 2) inside the footprint of any box (K, 7) grown by ``margin_m`` per side.

    One compiled pass (`_footprint_hits`) over boxes and points: with NumPy a scene's few dozen boxes
    cost a dozen array calls each, most of the time for the few hundred points of a call."""
    inside = np.zeros(len(xy), bool)
    if len(xy) == 0 or len(boxes) == 0:
        return inside
    b = np.ascontiguousarray(boxes, dtype=np.float64).reshape(-1, 7)
    hl, hw = 0.5 * b[:, 3] + margin_m, 0.5 * b[:, 4] + margin_m
    # The radius, cosine and sine as Python's math gives them (the NumPy form's bits).
    r = np.array([math.hypot(a, c) for a, c in zip(hl.tolist(), hw.tolist())])
    cos_yaw = np.array([math.cos(y) for y in b[:, 6].tolist()])
    sin_yaw = np.array([math.sin(y) for y in b[:, 6].tolist()])
    _footprint_hits(np.ascontiguousarray(xy, dtype=np.float64), b, hl, hw, r, cos_yaw, sin_yaw, inside)
    return inside


@numba.njit(cache=True, nogil=True)
def _footprint_hits(xy, boxes, hl, hw, r, cos_yaw, sin_yaw, inside):
    """Mark in `inside` the points xy (n, 2) within box k's footprint: |x - cx| and |y - cy| within
    r[k], then the box frame's |u| <= hl[k] and |w| <= hw[k] (the operations of the NumPy form)."""
    for k in range(boxes.shape[0]):
        cx, cy, c, s = boxes[k, 0], boxes[k, 1], cos_yaw[k], sin_yaw[k]
        for i in range(xy.shape[0]):
            if inside[i] or abs(xy[i, 0] - cx) > r[k] or abs(xy[i, 1] - cy) > r[k]:
                continue
            dx = xy[i, 0] - cx
            dy = xy[i, 1] - cy
            if abs(c * dx + s * dy) <= hl[k] and abs(-s * dx + c * dy) <= hw[k]:
                inside[i] = True


def _hat_dip(xy: np.ndarray, dip, grid_lo: np.ndarray, cell_m: float, grid_shape, cells: np.ndarray) -> np.ndarray:
    """`dip(xy)` (n,) of the leaks' dip grid, which is 0 but at the grid cells `cells` (P, 2): the
    bilinear interpolation (`ground_at`, clamped at the edges) is exactly 0.0 wherever none of the
    four cell centres around a point is a dip cell, so only the other points (`_near_dip_cells`) are
    interpolated. The same values as `dip(xy)`, for the few percent of a scene's points near a leak."""
    out = np.zeros(len(xy))
    if len(xy) == 0 or len(cells) == 0:
        return out
    xy = np.ascontiguousarray(xy, dtype=np.float64)
    is_dip = np.zeros(tuple(int(n) for n in grid_shape), dtype=np.bool_)
    is_dip[np.asarray(cells)[:, 0], np.asarray(cells)[:, 1]] = True
    near = np.zeros(len(xy), dtype=np.bool_)
    _near_dip_cells(xy, np.asarray(grid_lo, dtype=np.float64), float(cell_m), is_dip, near)
    if near.any():
        out[near] = dip(xy[near])
    return out


@numba.njit(cache=True, nogil=True)
def _near_dip_cells(xy, lo, cell, is_dip, near):
    """Mark in `near` the points xy (n, 2) one of whose four surrounding cell centres (the nodes of the
    bilinear interpolation, coordinates clamped to the grid) is a dip cell; NaN coordinates too."""
    n0, n1 = is_dip.shape
    for i in range(xy.shape[0]):
        u = (xy[i, 0] - lo[0]) / cell - 0.5
        w = (xy[i, 1] - lo[1]) / cell - 0.5
        if not (u == u and w == w):
            near[i] = True  # left to the interpolation itself
            continue
        u = min(max(u, 0.0), n0 - 1.0)
        w = min(max(w, 0.0), n1 - 1.0)
        a0, b0 = int(np.floor(u)), int(np.floor(w))
        a1, b1 = min(a0 + 1, n0 - 1), min(b0 + 1, n1 - 1)
        near[i] = is_dip[a0, b0] or is_dip[a0, b1] or is_dip[a1, b0] or is_dip[a1, b1]


def _object_index(label: np.ndarray, obj_id: np.ndarray) -> np.ndarray:
    """(n,) index into obj_id of each point's label, -1 for background and unboxed objects."""
    out = np.full(len(label), -1, np.int64)
    if len(obj_id) == 0:
        return out
    order = np.argsort(obj_id, kind="stable")
    sid = obj_id[order]
    pos = np.clip(np.searchsorted(sid, label), 0, len(sid) - 1)
    hit = (sid[pos] == label) & (label >= 0)
    out[hit] = order[pos[hit]]
    return out


def weighted_sample(weight: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` indices drawn without replacement with probability proportional to ``weight`` (n_w,) >= 0
    (Efraimidis-Spirakis keys u^(1/w)), in random order. With fewer than ``n`` positive weights every
    such point is used once and the rest drawn with replacement; with none, the weights are taken as 1."""
    pos = np.flatnonzero(weight > 0)
    if len(pos) == 0:
        pos = np.arange(len(weight))
        w = np.ones(len(weight))
    else:
        w = weight[pos].astype(np.float64)
    if len(pos) == 0:
        raise ValueError("no points to sample from")
    u = 1.0 - rng.random(len(pos))  # (0, 1]
    if len(pos) >= n:
        key = np.log(u) / w
        sel = pos[np.argpartition(key, len(pos) - n)[len(pos) - n:]]
    else:
        sel = np.concatenate([pos, rng.choice(pos, n - len(pos), replace=True, p=w / w.sum())])
    return rng.permutation(sel).astype(np.int64)


def dr_z_field(xy: np.ndarray, draws: dict) -> np.ndarray:
    """The smooth vertical distortion (m, (n,)) at xy (n, 2) (local frame) of a scene's draws: planar
    tilt + smile across the virtual track + residual heave along it, with the sensor effects' point-stage
    models: a roll bias's :func:`~sonardet.sim.effects.attitude.roll_bias_dz` (distance along the
    tilt azimuth x tan(tilt)), the SVP bias :func:`~sonardet.sim.effects.refraction.svp_bias_dz`
    k D (1/cos a - 1) of a flat seabed D below a virtual track (a from the across-track distance,
    clipped to the swath edge), and the uncompensated heave
    :func:`~sonardet.sim.effects.attitude.heave_dz` of a sinusoid along the track."""
    p = np.asarray(xy, np.float64) - draws["centre"]
    az, tr = draws["tilt_azimuth_rad"], draws["track_rad"]
    tilt = roll_bias_dz(p[:, 0] * math.cos(az) + p[:, 1] * math.sin(az), draws["tilt_rad"])
    along = p[:, 0] * math.cos(tr) + p[:, 1] * math.sin(tr)
    across = -p[:, 0] * math.sin(tr) + p[:, 1] * math.cos(tr) - draws["track_offset_m"]
    D = draws["smile_depth_m"]
    u = np.clip(across, -D * math.tan(math.radians(DR_HALF_SWATH_DEG)), D * math.tan(math.radians(DR_HALF_SWATH_DEG)))
    smile = svp_bias_dz(draws["smile_k"], D, flat_seabed_cos(D, u))
    heave = heave_dz(sinusoid(draws["heave_m"], draws["heave_wavelength_m"], along, draws["heave_phase_rad"]))
    return tilt + smile + heave


def _density_wave(xy: np.ndarray, draws: dict) -> np.ndarray:
    """Sum of the density field's cosine waves at xy (n, 2) (local frame)."""
    px, py = xy[:, 0] - draws["centre"][0], xy[:, 1] - draws["centre"][1]
    wave = np.zeros(len(xy))
    for a, lam, ph in zip(draws["density_azimuth_rad"], draws["density_wavelength_m"], draws["density_phase_rad"]):
        wave += np.cos((2 * math.pi / lam) * (px * math.cos(a) + py * math.sin(a)) + ph)
    return wave


def dr_density_weight(xy: np.ndarray, draws: dict) -> np.ndarray:
    """Relative sampling density (n,) at xy (n, 2) of a scene's draws (before the dropout blobs): the
    waves rescaled to [-1, 1] over the scene's point pool, weight = contrast^(wave / 2), so that the
    largest / smallest weight of the pool is the drawn contrast."""
    return _density_weight_of(_density_wave(np.asarray(xy, np.float64), draws), draws)


def _density_weight_of(wave: np.ndarray, draws: dict) -> np.ndarray:
    """`dr_density_weight` from the waves' sum (`_density_wave`) at the points."""
    lo, hi = draws["density_wave_range"]
    wave = (2.0 * wave - (lo + hi)) / (hi - lo) if hi > lo else np.zeros(len(wave))
    return np.exp((0.5 * math.log(draws["density_contrast"])) * wave)


def _line_coordinate(xy: np.ndarray, draws: dict) -> np.ndarray:
    """Across-track coordinate (m) of the virtual survey lines (strip k holds k*S <= v < (k+1)*S)."""
    p = np.asarray(xy, np.float64) - draws["centre"]
    tr = draws["track_rad"]
    return -p[:, 0] * math.sin(tr) + p[:, 1] * math.cos(tr) + draws["line_shift_m"]


def domain_randomise(scene: PreparedScene, params: dict, rng: np.random.Generator) -> DomainRandomised:
    """Randomised sensor effects on one prepared (ground-filtered) scene, then the ``n_points`` sample.

    The effects, in order (ranges: the ``dr_*`` parameters; reasoning: config.py's docstring). Where
    the simulator has the effect, its model comes from :mod:`sonardet.sim.effects` (named below):

    1. burial: objects resting on the seabed sink by U(``dr_burial_m``) with ``dr_burial_prob`` (an
       object stacked on a sunk one goes down with it); points now below the ground-filter height
       vanish; boxes and axes move down (burial: ``burial_depths``, ``burial_dz``);
    2. spikes: each of n candidate soundings (n = the scene's kept points) at uniform positions of
       the footprint is an upward flier with probability U(``dr_outlier_frac``), at a height
       U(``dr_outlier_height_m``) above the ground estimate, label -1 (outliers: ``draw_spikes``);
    3. seabed leaks: U{``dr_leak_patches``} random cells of the ground grid are lowered by
       U(``dr_leak_depth_m``) (a deep flier sets the cell minimum); the bilinear ground estimate dips
       as the cell's hat (half-width ``ground_cell_m``), the height of every point there rises, and
       seabed points (at the seabed density the filter removed, true height U(0, ground_height_m / 2))
       whose height now exceeds ``ground_height_m`` are added, label -1;
    4. sampling weights: a smooth density field with max/min ratio U(``dr_density_contrast``) times 0
       inside U{``dr_dropout_blobs``} ellipses centred on random points; the ``n_points`` are drawn
       with these weights without replacement (:func:`weighted_sample`);
    5. z field (:func:`dr_z_field`): tilt, smile and heave on z only (the ground estimate follows a
       smooth field); the boxes move with the field at their centre;
    6. line offsets: strips of width U(``dr_line_spacing_m``) along the virtual track, each shifted by
       N(0, sigma^2), sigma ~ U(``dr_line_offset_m``); in the overlap band a point takes either line;
       z += offset, height += offset - the lower of the two lines there; boxes take their strip's
       (line_offsets: ``line_offsets_m``, ``line_offset_dz``);
    7. range noise: z and height += N(0, sigma^2), sigma ~ U(``dr_range_noise_m``) (the sensor's
       range noise: ``noise.range_noise_dz``);
    8. roughness: object points (label >= 0) move by N(0, sigma^2) per axis, sigma ~ U(``dr_roughness_m``)
       (roughness: ``roughness_point_offsets``);
    9. shape (``dr_shape_prob`` > 0): objects drawn with that probability get thicker or thinner and a
       fouling shell: their points move along their upward surface normals (:func:`dr_shape_offsets`).

    Generated points never fall inside a gt box footprint grown by ``DR_BOX_MARGIN_M``. All random
    numbers come from ``rng`` (one draw per scene, then one child stream per effect).
    """
    base = int(rng.integers(0, 2**63 - 1))
    g = {name: np.random.default_rng([base, i]) for i, name in enumerate(DR_STREAMS)}
    st = _DRState.of(scene, params)
    _dr_burial(st, scene, params, g["burial"])
    q, hq = _dr_spikes(st, scene, params, g["outliers"])
    out_xyz = np.c_[q, st.ground(q) + hq] if len(q) else np.zeros((0, 3))
    out_h, leak_xyz, leak_h = _dr_leaks(st, scene, params, g["leak"], q, hq)
    st.pool((out_xyz, out_h), (leak_xyz, leak_h))
    weight = _dr_weights(st, params, g["density"], g["dropout"])
    idx = weighted_sample(weight, int(params["n_points"]), g["sample"])
    st.xyz, st.h, st.label, st.src = st.xyz[idx], st.h[idx], st.label[idx], st.src[idx]
    _dr_z_field(st, params, g["zfield"])
    _dr_lines(st, params, g["lines"])
    _dr_noise(st, params, g["noise"])
    _dr_roughness(st, params, g["roughness"])
    _dr_shape(st, scene, params, g["shape"])
    return DomainRandomised(st.xyz.astype(np.float32), st.h.astype(np.float32), st.label,
                            st.boxes.astype(np.float32), st.axis.astype(np.float32), st.src, st.draws)


@dataclass
class _DRState:
    """The working copy of one scene under domain randomisation (local frame, float64): points xyz
    (n, 3), height h (n,), label (n,), src (n,) (see :class:`DomainRandomised`), boxes (K, 7), axis
    (K, 3), the draws so far, and the scene's ground model (:func:`_ground_model`) and filter."""

    xyz: np.ndarray
    h: np.ndarray
    label: np.ndarray
    src: np.ndarray
    boxes: np.ndarray
    axis: np.ndarray
    draws: dict
    ground: object
    lo: np.ndarray
    hi: np.ndarray
    grid_lo: np.ndarray
    grid_shape: tuple
    thr: float
    use_filter: bool
    cell: float

    @classmethod
    def of(cls, scene: PreparedScene, params: dict) -> _DRState:
        cell = float(params["ground_cell_m"])
        ground, lo, hi, grid_lo, grid_shape = _ground_model(scene, cell)
        boxes = scene.boxes.astype(np.float64)
        axis = (boxes[:, :3].copy() if scene.axis is None else np.asarray(scene.axis, np.float64).copy())
        return cls(scene.xyz.astype(np.float64), scene.height.astype(np.float64), scene.label.astype(np.int64),
                   np.arange(len(scene.xyz)), boxes, axis, {"centre": 0.5 * (lo + hi)}, ground, lo, hi, grid_lo,
                   grid_shape, float(params["ground_height_m"]), bool(params["ground_filter"]), cell)

    def pool(self, spikes, leaks) -> None:
        """Append the spikes (xyz, height) and leaked seabed points (xyz, height) to the points."""
        (out_xyz, out_h), (leak_xyz, leak_h) = spikes, leaks
        self.xyz = np.concatenate([self.xyz, out_xyz, leak_xyz])
        self.h = np.concatenate([self.h, out_h, leak_h])
        self.label = np.concatenate([self.label, np.full(len(out_xyz) + len(leak_xyz), -1, np.int64)])
        self.src = np.concatenate([self.src, np.full(len(out_xyz), -2), np.full(len(leak_xyz), -1)]).astype(np.int64)


def _dr_burial(st: _DRState, scene: PreparedScene, params: dict, r: np.random.Generator) -> None:
    """1. Sink resting objects (and what is stacked on them); drop their points below the filter."""
    K = len(st.boxes)
    u = r.random(K)
    # Each object draws its own depth (no arrangement groups here: stacking is found below).
    depth = burial_depths(np.full(K, -1), params["dr_burial_m"], r)
    sink = np.zeros(K)
    boxes = st.boxes
    if K:
        bottom = boxes[:, 2] - 0.5 * boxes[:, 5]
        resting = bottom - st.ground(boxes[:, :2]) <= DR_REST_TOL_M
        sink = np.where((u < float(params["dr_burial_prob"])) & resting, depth, 0.0)
        # an element stacked on a sunk one (footprints overlapping, bottom higher) goes down with it
        reach = 0.5 * np.maximum(boxes[:, 3], boxes[:, 4])
        on_top = ((np.hypot(*(boxes[:, None, :2] - boxes[None, :, :2]).transpose(2, 0, 1)) < reach[:, None] + reach)
                  & (bottom[:, None] > bottom[None, :] + DR_REST_TOL_M) & ~resting[:, None])
        sink = np.maximum(sink, np.max(np.where(on_top, sink[None, :], 0.0), axis=1))
    keep = np.ones(len(st.xyz), bool)
    if np.any(sink > 0):
        dz = burial_dz(_object_index(st.label, scene.obj_id), sink)
        st.xyz[:, 2] += dz
        st.h += dz
        keep = ~((dz < 0) & ((st.h <= st.thr) if st.use_filter else (st.h < 0.0)))
        if not keep.any():  # a scene made of one sunk object: keep its points rather than none
            keep[:] = True
        st.boxes[:, 2] -= sink
        st.axis[:, 2] -= sink
    st.draws["burial_m"] = sink
    st.xyz, st.h, st.label, st.src = st.xyz[keep], st.h[keep], st.label[keep], st.src[keep]


def _dr_spikes(st: _DRState, scene: PreparedScene, params: dict, r: np.random.Generator):
    """2. Upward fliers above the ground estimate; returns (xy (m, 2), height above ground (m,))."""
    frac = _draw(r, params["dr_outlier_frac"])
    lo_m, hi_m = float(params["dr_outlier_height_m"][0]), float(params["dr_outlier_height_m"][1])
    n = len(scene.xyz)
    q = r.uniform(st.lo, st.hi, (n, 2))
    # Downward spikes end below the ground estimate, where the filter removes them (their other
    # effect, a dip of the estimate, is the leak below): only upward ones.
    spike, hq = draw_spikes(n, frac, hi_m, r, low_fraction=lo_m / hi_m if hi_m > 0 else 0.0, p_negative=0.0)
    q, hq = q[spike], hq[spike]
    ok = ~_in_box_footprints(q, st.boxes, DR_BOX_MARGIN_M)
    q, hq = q[ok], hq[ok]
    st.draws.update(outlier_frac=frac, n_outliers=len(q))
    return q, hq


def _dr_leaks(st: _DRState, scene: PreparedScene, params: dict, r: np.random.Generator, q: np.ndarray,
              hq: np.ndarray):
    """3. Seabed leaks: a deep flier lowers its cell's minimum by d; the bilinear ground estimate dips
    as that cell's hat (half-width one cell), so heights there rise (st.h, and the spikes' at q with
    heights hq) and seabed points get through. Returns (spike heights, leaked xyz (m, 3), their
    heights (m,))."""
    cell, lo, hi, thr = st.cell, st.lo, st.hi, st.thr
    n_patch = _draw_int(r, params["dr_leak_patches"])
    cells = np.c_[r.integers(0, st.grid_shape[0], n_patch), r.integers(0, st.grid_shape[1], n_patch)]
    dips = r.uniform(float(params["dr_leak_depth_m"][0]), float(params["dr_leak_depth_m"][1]), n_patch)
    centres = st.grid_lo + (cells + 0.5) * cell
    n_removed = max(int(scene.n_raw) - len(scene.xyz), 0) if st.use_filter else 0
    area = float(np.prod(np.maximum(hi - lo, 1e-6)))
    rho = n_removed / area  # seabed soundings per m^2 that the ground filter removed
    leak_xy, leak_h0, leak_h = np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    out_h = hq
    if n_patch:
        dgrid = np.zeros(st.grid_shape)
        np.maximum.at(dgrid, (cells[:, 0], cells[:, 1]), dips)  # the deepest flier sets a cell's minimum

        def dip(xy):
            return ground_at(st.grid_lo, dgrid, cell, xy)

        counts = r.poisson(rho * (2 * cell) ** 2, n_patch)
        owner = np.repeat(np.arange(n_patch), counts)
        leak_xy = centres[owner] + r.uniform(-cell, cell, (len(owner), 2))
        leak_h0 = r.uniform(0.0, 0.5 * thr, len(owner))
        lx, ly = leak_xy[:, 0], leak_xy[:, 1]
        ok = (lx >= lo[0]) & (lx <= hi[0]) & (ly >= lo[1]) & (ly <= hi[1])
        for i in range(n_patch - 1):  # a spot covered by an earlier patch already has its seabed points
            ok &= (owner <= i) | (np.abs(lx - centres[i, 0]) >= cell) | (np.abs(ly - centres[i, 1]) >= cell)
        leak_xy, leak_h0 = leak_xy[ok], leak_h0[ok]
        leak_h = leak_h0 + dip(leak_xy)
        ok = leak_h > thr
        leak_xy, leak_h0, leak_h = leak_xy[ok], leak_h0[ok], leak_h[ok]
        ok = ~_in_box_footprints(leak_xy, st.boxes, DR_BOX_MARGIN_M)
        leak_xy, leak_h0, leak_h = leak_xy[ok], leak_h0[ok], leak_h[ok]
        st.h = st.h + _hat_dip(st.xyz[:, :2], dip, st.grid_lo, cell, st.grid_shape, cells)
        out_h = hq + dip(q)
    leak_xyz = np.c_[leak_xy, st.ground(leak_xy) + leak_h0] if len(leak_xy) else np.zeros((0, 3))
    st.draws.update(leak_centres=centres, leak_depths_m=dips, n_leak=len(leak_xy))
    return out_h, leak_xyz, leak_h


def _dr_weights(st: _DRState, params: dict, r_density: np.random.Generator,
                r_dropout: np.random.Generator) -> np.ndarray:
    """4. Sampling weights (n,) of the pool: the smooth density field, 0 inside the dropout blobs."""
    xyz, draws = st.xyz, st.draws
    r = r_density
    draws.update(density_contrast=_draw(r, params["dr_density_contrast"]),
                 density_azimuth_rad=r.uniform(0.0, 2 * math.pi, DR_DENSITY_WAVES),
                 density_wavelength_m=r.uniform(*DR_DENSITY_WAVELENGTH_M, DR_DENSITY_WAVES),
                 density_phase_rad=r.uniform(0.0, 2 * math.pi, DR_DENSITY_WAVES))
    wave = _density_wave(xyz[:, :2], draws)
    draws["density_wave_range"] = (float(wave.min()), float(wave.max())) if len(wave) else (0.0, 0.0)
    weight = _density_weight_of(wave, draws)  # the waves once: `dr_density_weight` of the same points
    r = r_dropout
    n_blob = _draw_int(r, params["dr_dropout_blobs"])
    bc = xyz[r.integers(0, len(xyz), n_blob), :2]
    ba = r.uniform(float(params["dr_dropout_radius_m"][0]), float(params["dr_dropout_radius_m"][1]), n_blob)
    bb = ba / r.uniform(1.0, DR_BLOB_ASPECT, n_blob)
    bt = r.uniform(0.0, math.pi, n_blob)
    for j in range(n_blob):
        near = np.flatnonzero((np.abs(xyz[:, 0] - bc[j, 0]) <= ba[j]) & (np.abs(xyz[:, 1] - bc[j, 1]) <= ba[j]))
        d = xyz[near, :2] - bc[j]
        a = (math.cos(bt[j]) * d[:, 0] + math.sin(bt[j]) * d[:, 1]) / max(ba[j], 1e-9)
        b = (-math.sin(bt[j]) * d[:, 0] + math.cos(bt[j]) * d[:, 1]) / max(bb[j], 1e-9)
        weight[near[a * a + b * b <= 1.0]] = 0.0
    draws["blobs"] = np.c_[bc, ba, bb, bt] if n_blob else np.zeros((0, 5))
    return weight


def _dr_z_field(st: _DRState, params: dict, r: np.random.Generator) -> None:
    """5. Smooth z field: tilt + smile + heave (z only; the ground estimate follows it)."""
    half = 0.5 * float(np.max(st.hi - st.lo))
    st.draws.update(
        tilt_rad=math.radians(_draw(r, params["dr_tilt_deg"])), tilt_azimuth_rad=float(r.uniform(0, 2 * math.pi)),
        smile_k=_draw(r, params["dr_smile_coeff"]), smile_depth_m=float(params["dr_smile_depth_m"]),
        track_rad=float(r.uniform(0, math.pi)), track_offset_m=float(r.uniform(-half, half)),
        heave_m=_draw(r, params["dr_heave_m"]), heave_wavelength_m=_draw(r, params["dr_heave_wavelength_m"]),
        heave_phase_rad=float(r.uniform(0, 2 * math.pi)))
    st.xyz[:, 2] += dr_z_field(st.xyz[:, :2], st.draws)
    if len(st.boxes):
        fz = dr_z_field(st.boxes[:, :2], st.draws)
        st.boxes[:, 2] += fz
        st.axis[:, 2] += fz


def _dr_lines(st: _DRState, params: dict, r: np.random.Generator) -> None:
    """6. Vertical offsets of virtual survey lines (strips along the track, mixed in the overlaps)."""
    sigma = _draw(r, params["dr_line_offset_m"])
    S = _draw(r, params["dr_line_spacing_m"])
    st.draws.update(line_sigma_m=sigma, line_spacing_m=S, line_shift_m=float(r.uniform(0.0, S)))
    band = 0.5 * float(params["dr_line_overlap"]) * S
    K = len(st.boxes)
    v = _line_coordinate(st.xyz[:, :2], st.draws)
    vb = _line_coordinate(st.boxes[:, :2], st.draws) if K else np.zeros(0)
    line = np.floor((v + r.uniform(-band, band, len(v))) / S).astype(np.int64)
    low_line = np.floor((v - band) / S).astype(np.int64)
    high_line = np.floor((v + band) / S).astype(np.int64)
    box_line = np.floor(vb / S).astype(np.int64)
    i0 = int(min(low_line.min(), box_line.min(initial=low_line.min())))
    i1 = int(max(high_line.max(), box_line.max(initial=high_line.max())))
    offs = line_offsets_m(sigma, r.standard_normal(i1 - i0 + 1))
    dz = line_offset_dz(offs, line - i0)
    st.xyz[:, 2] += dz
    st.h += dz - np.minimum(line_offset_dz(offs, low_line - i0), line_offset_dz(offs, high_line - i0))
    if K:
        st.boxes[:, 2] += line_offset_dz(offs, box_line - i0)
        st.axis[:, 2] += line_offset_dz(offs, box_line - i0)
    st.draws.update(line_first=i0, line_offsets_m=offs)


def _dr_noise(st: _DRState, params: dict, r: np.random.Generator) -> None:
    """7. Range noise on z and the height feature."""
    sigma = _draw(r, params["dr_range_noise_m"])
    dz = range_noise_dz(len(st.xyz), sigma, r)
    st.xyz[:, 2] += dz
    st.h += dz
    st.draws["noise_sigma_m"] = sigma


def _dr_roughness(st: _DRState, params: dict, r: np.random.Generator) -> None:
    """8. Object roughness: object points move by N(0, sigma^2) per axis."""
    sigma = _draw(r, params["dr_roughness_m"])
    d = roughness_point_offsets(len(st.xyz), sigma, r)
    obj = st.label >= 0
    st.xyz[obj] += d[obj]
    st.h[obj] += d[obj, 2]
    st.draws["roughness_sigma_m"] = sigma


def upward_normals(xyz: np.ndarray, k: int = DR_SHAPE_NEIGHBOURS) -> np.ndarray:
    """Unit surface normals (n, 3) of points (n, 3) of one object (m): the least-variance axis of each
    point's k nearest points (itself included), turned so that n_z >= 0. Fewer than 3 points: +z."""
    n = len(xyz)
    out = np.tile([0.0, 0.0, 1.0], (n, 1))
    if n < 3:
        return out
    from scipy.spatial import cKDTree

    _, nb = cKDTree(xyz).query(xyz, k=min(k, n))
    q = xyz[nb] - xyz[nb].mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", q, q))
    out = vec[:, :, 0]
    return np.where(out[:, 2:3] < 0, -out, out)


def dr_shape_offsets(xyz: np.ndarray, thickness_m: float, fouling_m: float, wave: np.ndarray,
                     phase_rad: float) -> np.ndarray:
    """Displacements (n, 3, m) of one object's points (n, 3): along their upward normals
    (:func:`upward_normals`) by `thickness_m` (+ thicker, - thinner) where |n_z| >= DR_SHAPE_MIN_NZ,
    plus an uneven fouling shell `fouling_m` x (0.5 + 0.5 sin(wave . p + phase_rad)) (wave: (3,)
    wave vector, rad/m)."""
    nrm = upward_normals(xyz)
    foul = fouling_m * (0.5 + 0.5 * np.sin(xyz @ wave + phase_rad))
    d = np.where(np.abs(nrm[:, 2]) >= DR_SHAPE_MIN_NZ, thickness_m, 0.0) + foul
    return d[:, None] * nrm


def _dr_shape(st: _DRState, scene: PreparedScene, params: dict, r: np.random.Generator) -> None:
    """9. Objects unlike their models: thicker/thinner and fouled (``dr_shape_*``; off at probability 0)."""
    prob = float(params["dr_shape_prob"])
    K = len(st.boxes)
    st.draws["shape_offset_m"] = np.zeros(K)
    if prob <= 0 or K == 0:
        return
    classes = list(params["classes"])
    half = np.array([float(params["dr_shape_half_thickness_m"][classes[c]]) for c in scene.cls])
    on = r.random(K) < prob
    frac = float(params["dr_shape_offset_frac"])
    thick = np.where(on, r.uniform(-frac, frac, K) * half, 0.0)
    foul = np.where(on, r.uniform(*map(float, params["dr_shape_fouling_m"]), K), 0.0)
    lam = r.uniform(*map(float, params["dr_shape_wavelength_m"]), K)
    direction = r.normal(size=(K, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    phase = r.uniform(0.0, 2.0 * math.pi, K)
    oi = _object_index(st.label, scene.obj_id)
    for k in np.flatnonzero(on):
        idx = np.flatnonzero(oi == k)
        if len(idx) == 0:
            continue
        d = dr_shape_offsets(st.xyz[idx], thick[k], foul[k], 2.0 * math.pi / lam[k] * direction[k], phase[k])
        st.xyz[idx] += d
        st.h[idx] += d[:, 2]
    st.draws["shape_offset_m"] = thick
    st.draws["shape_fouling_m"] = foul


def collate(items: list[tuple], device) -> dict:
    """Stack samples into a batch.

    items: list of (xyz (N, 3), height (N,), boxes (K, 7), cls (K,)) numpy arrays with equal N.
    Returns {"xyz": (B, N, 3), "features": (B, N, 1) (channel-last), "gt_boxes": (B, Kmax, 7), "gt_cls": (B, Kmax) with
    -1 padding} as float32 / int64 tensors on ``device``.
    """
    B = len(items)
    N = items[0][0].shape[0]
    kmax = max(1, max(len(it[2]) for it in items))
    xyz = np.stack([it[0] for it in items]).astype(np.float32)
    feat = np.stack([it[1] for it in items]).astype(np.float32)[:, :, None]
    gb = np.zeros((B, kmax, 7), np.float32)
    gc = np.full((B, kmax), -1, np.int64)
    for b, it in enumerate(items):
        k = len(it[2])
        if it[0].shape[0] != N:
            raise ValueError("all scenes of a batch need the same number of points")
        gb[b, :k] = it[2]
        gc[b, :k] = it[3]
    return {
        "xyz": torch.from_numpy(xyz).to(device),
        "features": torch.from_numpy(feat).to(device),
        "gt_boxes": torch.from_numpy(gb).to(device),
        "gt_cls": torch.from_numpy(gc).to(device),
    }


def read_json(path) -> dict:
    """Small helper: read a JSON file (errors name the file and the line: `sonardet.io.artifacts`)."""
    return read_json_file(path, "JSON file")
