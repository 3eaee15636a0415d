"""The scene file pair: ``{scene}.npz`` (the soundings) and ``{scene}.json`` (the annotations).

Soundings file, written with ``numpy.savez`` (uncompressed)::

    xyz    (N, 3) float64  scene frame (x east, y north, z up), metres, finite
    ping   (N,)    integer ping index of each sounding
    beam   (N,)    integer beam index
    line   (N,)    integer survey line index
    label  (N,)    integer object id of the sounding (``objects[*].id`` of the JSON), or < 0: seabed (-1)
                   and other non-object returns

Annotations file: the scene document of ``sonardet.io.annotations`` (schema_version, scene, seed,
config_hash, extent, objects with pose, box, n_points, visible, and whatever else the simulator
records), written as ``json.dumps(meta, indent=1)``.

:func:`write_scene` validates both before it writes either (both files or neither); :func:`read_scene_points`
reads the soundings and :func:`read_scene` (re-exported from ``sonardet.io.annotations``) the validated
annotations. Reading a scene needs numpy only: this module imports neither the simulator (MuJoCo,
Open3D, trimesh) nor pandas.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping

import numpy as np

from sonardet.io.annotations import read_scene, validate_scene
from sonardet.io.artifacts import FileReadError, read_npz
from sonardet.io.atomic import atomic_outputs, atomic_write_text

__all__ = ["SOUNDING_FIELDS", "read_scene", "read_scene_points", "write_scene"]

#: The per-sounding integer arrays of a scene's ``.npz`` besides ``xyz``, in file order.
SOUNDING_FIELDS: tuple[str, ...] = ("ping", "beam", "line", "label")


def read_scene_points(path: str | os.PathLike) -> dict:
    """Read a scene's soundings (``{scene}.npz``): name -> array, ``xyz`` (N, 3) float64 metres in the
    scene frame and the per-sounding arrays (``ping``, ``beam``, ``line``, ``label``) as stored.

    Validates shapes, dtype and finiteness of ``xyz`` and the lengths of the per-sounding arrays;
    errors (``sonardet.io.artifacts.FileReadError``, a ValueError) name the file, the entry and the fix
    (a truncated or damaged file: delete it and rerun the step that writes it).
    """
    what = "scene soundings file"
    out = read_npz(path, what, required=("xyz",))
    xyz = out["xyz"]
    fix = f"not a valid {what}: delete it and rerun the step that writes it"
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise FileReadError(f"{path}: 'xyz' must be an (N,3) array, found shape {xyz.shape}; {fix}")
    if xyz.dtype != np.float64:
        raise FileReadError(f"{path}: 'xyz' must be float64, found {xyz.dtype}; {fix}")
    if not np.all(np.isfinite(xyz)):
        row = int(np.flatnonzero(~np.isfinite(xyz).all(1))[0])
        raise FileReadError(f"{path}: 'xyz' holds NaN/Inf at row {row}; {fix}")
    for k in SOUNDING_FIELDS:
        if k in out and len(out[k]) != len(xyz):
            raise FileReadError(f"{path}: '{k}' has {len(out[k])} entries for {len(xyz)} points; {fix}")
    return out


def _parts(scene) -> dict:
    """xyz, the sounding fields and meta of a `Scene`-like object (attributes) or a mapping (keys)."""
    names = ("xyz", *SOUNDING_FIELDS, "meta")
    if isinstance(scene, Mapping):
        missing = [k for k in names if k not in scene]
        if missing:
            raise ValueError(f"write_scene: the scene lacks {missing}; it needs {list(names)}")
        return {k: scene[k] for k in names}
    missing = [k for k in names if not hasattr(scene, k)]
    if missing:
        raise ValueError(f"write_scene: {type(scene).__name__} lacks {missing}; it needs {list(names)}")
    return {k: getattr(scene, k) for k in names}


def _check_soundings(parts: dict, npz_path) -> None:
    """Refuse soundings that `read_scene_points` would refuse or misread (errors name the file)."""
    xyz = parts["xyz"]
    if not isinstance(xyz, np.ndarray) or xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"{npz_path}: 'xyz' must be an (N,3) array, got shape {np.shape(xyz)}")
    if xyz.dtype != np.float64:
        raise ValueError(f"{npz_path}: 'xyz' must be float64 (metres), found {xyz.dtype}")
    finite = np.isfinite(xyz).all(axis=1)
    if not finite.all():
        raise ValueError(f"{npz_path}: 'xyz' holds NaN/Inf at row {int(np.flatnonzero(~finite)[0])}; "
                         "a scene's soundings must be finite")
    for k in SOUNDING_FIELDS:
        arr = parts[k]
        if not isinstance(arr, np.ndarray) or arr.ndim != 1 or len(arr) != len(xyz):
            raise ValueError(f"{npz_path}: '{k}' must be a 1-D array of {len(xyz)} entries (one per sounding), "
                             f"got shape {np.shape(arr)}")
        if arr.dtype.kind not in "iu":
            raise ValueError(f"{npz_path}: '{k}' must hold integers, found {arr.dtype}")


def write_scene(scene, npz_path: str | os.PathLike, json_path: str | os.PathLike) -> None:
    """Write a scene's soundings (``npz_path``) and annotations (``json_path``), both or neither
    (``sonardet.io.atomic.atomic_outputs``).

    ``scene``: a ``sonardet.sim.scene.Scene`` or any object or mapping with ``xyz`` ((N, 3) float64,
    metres, scene frame), ``ping``, ``beam``, ``line``, ``label`` ((N,) integer arrays) and ``meta`` (the
    scene document). Both parts are validated before anything is written: the arrays' shapes, dtypes,
    finite ``xyz`` and per-sounding lengths, and the document with
    ``sonardet.io.annotations.validate_scene`` (any scene id: the file name is not checked). Raises
    ValueError naming the file and the field. The arrays are stored as given (``numpy.savez``) and the
    document as given (``json.dumps(meta, indent=1)``), so equal scenes give equal bytes.
    """
    parts = _parts(scene)
    _check_soundings(parts, npz_path)
    validate_scene(parts["meta"], json_path)
    with atomic_outputs([npz_path, json_path]) as (npz_tmp, json_tmp):
        with open(npz_tmp, "wb") as fh:
            np.savez(fh, **{k: parts[k] for k in ("xyz", *SOUNDING_FIELDS)})
        atomic_write_text(json_tmp, json.dumps(parts["meta"], indent=1))
