"""Ground-truth scene labels and detections as JSON (DESIGN.md section 3), validated on read and write.

Scene file `results/scenes/{scene}.json`::

    {"schema_version": 1, "scene": "<id>", "seed": <int>, "config_hash": "<str>", "extent": <any JSON>,
     "objects": [{"id": <int>, "cls": "<class>", "pose": {"t": [x, y, z], "q": [w, x, y, z]},
                  "box": [x, y, z, l, w, h, yaw], "n_points": <int >= 0>, "visible": <bool>}, ...]}

Detection file `results/detections/{method}/{dataset}/{scene}.json`::

    {"schema_version": 1, "scene": "<id>", "method": "<str>",
     "detections": [{"cls": "<class>", "box": [x, y, z, l, w, h, yaw], "score": <float>,
                     "pose": {"t": [...], "q": [...]} (optional), "extras": {...} (optional)}, ...]}

Units and frames: scene frame, metres and radians; `box` is the gravity-aligned evaluation box with
extents l, w, h >= 0 and yaw about +z; `pose` the mesh's canonical frame (quaternion scalar first).

Every error is a ValueError whose message starts with the file (or the in-memory source label), names
the entry (`objects[3].box`), says what is wrong and how to fix it. Writes are atomic (temporary file in
the target directory, then `os.replace`), so a reader never sees a half-written file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Iterable

import numpy as np

from .. import SCHEMA_VERSION
from .artifacts import read_json_file
from .atomic import atomic_write_text

SCENE_KEYS = ("schema_version", "scene", "seed", "config_hash", "extent", "objects")
OBJECT_KEYS = ("id", "cls", "pose", "box", "n_points", "visible")
DETECTIONS_KEYS = ("schema_version", "scene", "method", "detections")
DETECTION_KEYS = ("cls", "box", "score")


class AnnotationError(ValueError):
    """An invalid scene or detection file (a ValueError naming the file, the entry and the fix)."""


def _fail(source, where: str, msg: str):
    loc = f"{source}: {where}: " if where else f"{source}: "
    raise AnnotationError(loc + msg)


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def _is_real(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


def _check_schema_version(doc: dict, source) -> None:
    v = doc.get("schema_version")
    if not _is_int(v) or int(v) != SCHEMA_VERSION:
        _fail(source, "schema_version",
              f"unknown schema_version {v!r}; this sonardet reads and writes schema_version {SCHEMA_VERSION}. "
              "Regenerate the file with this version of sonardet (or convert it).")


def _check_keys(d, keys: Iterable[str], source, where: str) -> None:
    if not isinstance(d, dict):
        _fail(source, where, f"expected a JSON object, got {type(d).__name__}")
    missing = [k for k in keys if k not in d]
    if missing:
        _fail(source, where, f"missing key(s) {', '.join(map(repr, missing))}; required keys: {', '.join(keys)}")


def check_class(cls, classes, source, where: str) -> str:
    """Return cls if it is a non-empty string in `classes` (None: any); else raise naming source/where."""
    if not isinstance(cls, str) or not cls:
        _fail(source, where, f"class must be a non-empty string, got {cls!r}")
    if classes is not None and cls not in classes:
        _fail(source, where, f"unknown class {cls!r}; known classes: {', '.join(classes)}. "
                             "Fix the file or add the class to the configured classes.")
    return cls


def _check_vector(v, n: int, source, where: str, name: str) -> list[float]:
    if not isinstance(v, (list, tuple, np.ndarray)) or len(v) != n or not all(_is_real(x) for x in v):
        _fail(source, where, f"{name} must be a list of {n} numbers, got {v!r}")
    out = [float(x) for x in v]
    if not all(math.isfinite(x) for x in out):
        _fail(source, where, f"{name} has NaN/Inf value(s): {out}; every value must be finite")
    return out


def check_box(box, source, where: str) -> list[float]:
    """Return box as 7 floats if finite with extents >= 0 (m); else raise naming source/where."""
    b = _check_vector(box, 7, source, where, "box [x, y, z, l, w, h, yaw]")
    if min(b[3:6]) < 0:
        _fail(source, where, f"box extents l, w, h must be >= 0 m, got {b[3:6]}")
    return b


def _check_pose(pose, source, where: str) -> dict:
    _check_keys(pose, ("t", "q"), source, where)
    t = _check_vector(pose["t"], 3, source, where + ".t", "translation t [x, y, z]")
    q = _check_vector(pose["q"], 4, source, where + ".q", "quaternion q [w, x, y, z]")
    if math.sqrt(sum(x * x for x in q)) < 1e-12:
        _fail(source, where + ".q", f"quaternion must be non-zero, got {q}")
    return {"t": t, "q": q}


def _check_scene_id(doc, source, expected_scene) -> None:
    sid = doc.get("scene")
    if not isinstance(sid, str) or not sid:
        _fail(source, "scene", f"scene id must be a non-empty string, got {sid!r}")
    if expected_scene is not None and sid != expected_scene:
        _fail(source, "scene", f"scene id {sid!r} does not match the expected {expected_scene!r} "
                               "(file name stem); rename the file or fix its 'scene' field")


def validate_scene(doc, source="<scene>", classes=None, expected_scene: str | None = None) -> dict:
    """Check a scene document (see module doc) and return a normalized copy (floats, lists).

    classes: allowed class names (None: any non-empty string). expected_scene: required value of
    `scene` (None: not checked). Raises AnnotationError (a ValueError) naming `source` and the entry.
    """
    _check_keys(doc, SCENE_KEYS, source, "")
    _check_schema_version(doc, source)
    _check_scene_id(doc, source, expected_scene)
    if not _is_int(doc["seed"]):
        _fail(source, "seed", f"seed must be an integer, got {doc['seed']!r}")
    if not isinstance(doc["config_hash"], str):
        _fail(source, "config_hash", f"config_hash must be a string, got {doc['config_hash']!r}")
    if not isinstance(doc["objects"], list):
        _fail(source, "objects", f"objects must be a list, got {type(doc['objects']).__name__}")
    objects, ids = [], set()
    for i, o in enumerate(doc["objects"]):
        where = f"objects[{i}]"
        _check_keys(o, OBJECT_KEYS, source, where)
        if not _is_int(o["id"]):
            _fail(source, where + ".id", f"id must be an integer, got {o['id']!r}")
        if int(o["id"]) in ids:
            _fail(source, where + ".id", f"duplicate object id {o['id']}; ids must be unique within a scene")
        ids.add(int(o["id"]))
        if not _is_int(o["n_points"]) or o["n_points"] < 0:
            _fail(source, where + ".n_points", f"n_points must be an integer >= 0, got {o['n_points']!r}")
        if not isinstance(o["visible"], (bool, np.bool_)):
            _fail(source, where + ".visible", f"visible must be true or false, got {o['visible']!r}")
        obj = dict(o)
        obj.update(
            id=int(o["id"]),
            cls=check_class(o["cls"], classes, source, where + ".cls"),
            pose=_check_pose(o["pose"], source, where + ".pose"),
            box=check_box(o["box"], source, where + ".box"),
            n_points=int(o["n_points"]),
            visible=bool(o["visible"]),
        )
        objects.append(obj)
    out = dict(doc)
    out.update(schema_version=int(doc["schema_version"]), seed=int(doc["seed"]), objects=objects)
    return out


def validate_detections(doc, source="<detections>", classes=None, expected_scene: str | None = None) -> dict:
    """Check a detections document (see module doc) and return a normalized copy.

    Scores must be finite numbers; `extras` defaults to {} and `pose` is checked when present.
    classes / expected_scene as in `validate_scene`. Raises AnnotationError naming `source` and the entry.
    """
    _check_keys(doc, DETECTIONS_KEYS, source, "")
    _check_schema_version(doc, source)
    _check_scene_id(doc, source, expected_scene)
    if not isinstance(doc["method"], str):
        _fail(source, "method", f"method must be a string, got {doc['method']!r}")
    if not isinstance(doc["detections"], list):
        _fail(source, "detections", f"detections must be a list, got {type(doc['detections']).__name__}")
    dets = []
    for i, d in enumerate(doc["detections"]):
        where = f"detections[{i}]"
        _check_keys(d, DETECTION_KEYS, source, where)
        s = d["score"]
        if not _is_real(s) or not math.isfinite(float(s)):
            _fail(source, where + ".score", f"score must be a finite number, got {s!r}")
        det = dict(d)
        det.update(
            cls=check_class(d["cls"], classes, source, where + ".cls"),
            box=check_box(d["box"], source, where + ".box"),
            score=float(s),
            extras=d.get("extras", {}),
        )
        if not isinstance(det["extras"], dict):
            _fail(source, where + ".extras", f"extras must be a JSON object, got {det['extras']!r}")
        if d.get("pose") is not None:
            det["pose"] = _check_pose(d["pose"], source, where + ".pose")
        dets.append(det)
    out = dict(doc)
    out.update(schema_version=int(doc["schema_version"]), detections=dets)
    return out


def _read_json(path, what: str) -> dict:
    """The JSON document of `path`; a missing file is an AnnotationError, a damaged one (truncated, not
    UTF-8, not JSON) a FileReadError naming the file, the line and the fix (both ValueErrors)."""
    path = Path(path)
    if not path.exists():
        raise AnnotationError(f"{path}: file not found")
    return read_json_file(path, what)


def _expected(path, expected_scene, check_filename: bool):
    if expected_scene is not None:
        return expected_scene
    return Path(path).stem if check_filename else None


def read_scene(path, classes=None, expected_scene: str | None = None, check_filename: bool = True) -> dict:
    """Read and validate a scene file `scenes/{scene}.json`; returns the normalized document.

    The scene id must equal `expected_scene` if given, else the file-name stem (unless check_filename is
    False). Objects keep their `visible` flag; evaluation drops invisible ones.
    """
    return validate_scene(_read_json(path, "scene annotations file"), path, classes, _expected(path, expected_scene, check_filename))


def read_detections(path, classes=None, expected_scene: str | None = None, check_filename: bool = True) -> dict:
    """Read and validate a detection file `detections/{method}/{dataset}/{scene}.json`.

    The scene id is checked as in `read_scene`. Returns the normalized document (scores as float,
    `extras` present on every detection).
    """
    return validate_detections(_read_json(path, "detections file"), path, classes, _expected(path, expected_scene, check_filename))


def to_builtin(x):
    """Convert numpy arrays/scalars (nested in dicts, lists, tuples) to plain Python for JSON."""
    if isinstance(x, dict):
        return {str(k): to_builtin(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_builtin(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_builtin(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def _dump(path, doc) -> None:
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")


def write_scene(path, scene: dict, classes=None) -> dict:
    """Validate a scene document and write it atomically to `path` (JSON). Returns what was written.

    `schema_version` is filled in with sonardet.SCHEMA_VERSION when absent; numpy values are converted.
    The scene id must match the file-name stem.
    """
    doc = to_builtin(dict(scene))
    doc.setdefault("schema_version", SCHEMA_VERSION)
    doc = validate_scene(doc, path, classes, Path(path).stem)
    _dump(path, doc)
    return doc


def write_detections(path, scene: str, method: str, detections: list, classes=None) -> dict:
    """Write the detections of one scene atomically to `path` (JSON). Returns what was written.

    detections: list of {cls, box [x,y,z,l,w,h,yaw], score, pose (optional), extras (optional)}. The
    scene id must match the file-name stem.
    """
    doc = {"schema_version": SCHEMA_VERSION, "scene": scene, "method": method,
           "detections": to_builtin(list(detections))}
    doc = validate_detections(doc, path, classes, Path(path).stem)
    _dump(path, doc)
    return doc
