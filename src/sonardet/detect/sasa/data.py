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
"""

from __future__ import annotations

import json
import logging
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from ...io.annotations import read_scene
from ...sim.scene import load_scene_points

log = logging.getLogger(__name__)

__all__ = ["PreparedScene", "ground_height", "prepare_points", "prepare_scene", "scene_paths", "sample_points",
           "augment", "canonicalize_boxes", "collate", "PaddingWarning", "wrap_yaw"]


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


def ground_height(xyz: np.ndarray, cell_m: float) -> np.ndarray:
    """Ground elevation (m) under each point (N,) from the grid minimum (cell ``cell_m``, bilinear).

    Args:
        xyz: (N, 3) float array (m), N >= 1.
        cell_m: cell size (m).
    Returns:
        (N,) float64 ground z at every point's (x, y).
    """
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
    u = (xy - lo) / cell_m - 0.5  # cell-centre coordinates
    return ndimage.map_coordinates(grid, [u[:, 0], u[:, 1]], order=1, mode="nearest")


def prepare_points(xyz: np.ndarray, params: dict, origin: np.ndarray | None = None):
    """Ground filter + local frame for a raw cloud (N, 3) float64 (scene frame, m).

    Returns (keep (N,) bool, local xyz (M, 3) float32, height (M,) float32, origin (3,) float64).
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or len(xyz) == 0:
        raise ValueError(f"points must be a non-empty (N, 3) array, got shape {xyz.shape}")
    ground = ground_height(xyz, float(params["ground_cell_m"]))
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
    return keep, local, h[keep].astype(np.float32), origin


def scene_paths(path) -> tuple[Path, Path]:
    """(npz, json) paths of a scene given either file (or the stem)."""
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".npz", ".json") else p
    return stem.with_suffix(".npz"), stem.with_suffix(".json")


def prepare_scene(path, params: dict, with_labels: bool = True) -> PreparedScene:
    """Load a scene (npz [+ json]) and prepare it (see module docstring). Labels need the json."""
    npz, js = scene_paths(path)
    pts = load_scene_points(npz)
    keep, local, height, origin = prepare_points(pts["xyz"], params)
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


def load_json(path) -> dict:
    """Small helper: read a JSON file."""
    return json.loads(Path(path).read_text(encoding="utf-8"))
