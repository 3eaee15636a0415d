"""Object metadata and the on-disk form of an object: `objects/{cls}.ply` + `objects/{cls}.json`."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from .. import SCHEMA_VERSION
from ..geometry import box_from_points, quat_multiply, quat_to_matrix, yaw_of_matrix
from ..io.atomic import atomic_write_bytes, atomic_write_text
from . import classes
from .meshes import SYMMETRY_CONTINUOUS, ObjectModel


@dataclass
class ObjectInfo:
    """An object class as the simulator and detectors load it (canonical frame, metres)."""

    cls: str
    mesh: trimesh.Trimesh
    convex_parts: list[np.ndarray]
    mass_kg: float
    volume_m3: float
    symmetry_order: int
    extents_m: np.ndarray
    #: Canonical-frame unit axes (K,3); the object rests upright when one of them points up.
    up_axes: np.ndarray
    #: Tumbled poses a detector tries on leftovers (sonardet.objects.classes.TUMBLE_MODES).
    tumble: dict
    #: The builder's description of the shape (e.g. a tetrapod's solved leg radii), from the JSON.
    spec: dict = field(default_factory=dict)

    def box(self, t, q) -> np.ndarray:
        """Evaluation box `[x,y,z,l,w,h,yaw]` of this object at pose (t, q=(w,x,y,z))."""
        return canonical_box(np.asarray(self.mesh.vertices), t, q, self.symmetry_order)


def object_info(model: ObjectModel, density_kg_m3: float) -> ObjectInfo:
    """The ObjectInfo of a freshly built object (what reading its written files gives, without them)."""
    meta = classes.get(model.cls).metadata()
    vol = float(model.mesh.volume)
    return ObjectInfo(cls=model.cls, mesh=model.mesh, convex_parts=list(model.convex_parts),
                      mass_kg=vol * float(density_kg_m3), volume_m3=vol, symmetry_order=int(model.symmetry_order),
                      extents_m=np.asarray(model.mesh.extents, dtype=np.float64),
                      up_axes=np.asarray(meta["up_axes"], dtype=np.float64), tumble=meta["tumble"],
                      spec=dict(model.spec))


def canonical_box(vertices, t, q, symmetry_order: int) -> np.ndarray:
    """Box of canonical vertices (N,3) posed at (t, q), unique for the physical placement.

    A rotationally symmetric object's pose is ambiguous, so its box must not depend on which of the
    equivalent poses is given: continuous symmetry gets yaw 0 (axis-aligned box); n-fold symmetry
    (tetrapods: 3) takes the equivalent rotation whose heading is closest to 0, i.e. yaw in
    [-pi/n, pi/n).
    """
    posed = np.asarray(vertices, dtype=np.float64) @ quat_to_matrix(q).T + np.asarray(t, dtype=np.float64)
    if symmetry_order == SYMMETRY_CONTINUOUS:
        return box_from_points(posed, 0.0)
    best = None
    for k in range(max(symmetry_order, 1)):
        h = np.pi * k / max(symmetry_order, 1)
        qk = quat_multiply(q, [np.cos(h), 0.0, 0.0, np.sin(h)])
        yaw = yaw_of_matrix(quat_to_matrix(qk))
        if best is None or abs(yaw) < abs(best) - 1e-12:
            best = yaw
    return box_from_points(posed, best)


def metadata(model: ObjectModel, density_kg_m3: float) -> dict:
    """JSON-ready metadata of a built object (dimensions, volume, mass, symmetry, convex parts)."""
    mesh = model.mesh
    vol = float(mesh.volume)
    return {
        "schema_version": SCHEMA_VERSION,
        "cls": model.cls,
        "extents_m": [float(v) for v in mesh.extents],
        "height_m": float(mesh.extents[2]),
        "volume_m3": vol,
        "spec_volume_m3": float(model.spec_volume_m3),
        "density_kg_m3": float(density_kg_m3),
        "mass_kg": vol * density_kg_m3,
        "symmetry_order": int(model.symmetry_order),
        "rotationally_symmetric": model.symmetry_order == SYMMETRY_CONTINUOUS,
        "n_vertices": int(len(mesh.vertices)),
        "n_faces": int(len(mesh.faces)),
        "watertight": bool(mesh.is_watertight),
        "spec": _jsonable(model.spec),
        **classes.get(model.cls).metadata(),
        "convex_parts": [np.round(p, 6).tolist() for p in model.convex_parts],
    }


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_object(model: ObjectModel, density_kg_m3: float, ply_path, json_path) -> dict:
    """Write the mesh (binary PLY) and its metadata (JSON), each atomically. Returns the metadata."""
    meta = metadata(model, density_kg_m3)
    atomic_write_bytes(ply_path, trimesh.exchange.ply.export_ply(model.mesh, encoding="binary"))
    atomic_write_text(json_path, json.dumps(meta, indent=1))
    return meta


def read_object(json_path, ply_path=None) -> ObjectInfo:
    """Read an object written by :func:`write_object` (PLY beside the JSON unless given)."""
    json_path = Path(json_path)
    ply_path = Path(ply_path) if ply_path else json_path.with_suffix(".ply")
    meta = json.loads(json_path.read_text())
    if meta.get("schema_version") != SCHEMA_VERSION:
        raise ValueError(
            f"{json_path}: schema_version {meta.get('schema_version')!r} is not {SCHEMA_VERSION}; "
            "rebuild it with `snakemake results/objects/<cls>.json`"
        )
    missing = [k for k in ("up_axes", "tumble") if k not in meta]
    if missing:
        raise ValueError(f"{json_path}: no {', '.join(missing)} (written by an older sonardet); rebuild it with "
                         "`snakemake results/objects/<cls>.json`")
    mesh = trimesh.load(ply_path, force="mesh", process=False)
    if len(mesh.faces) == 0:
        raise ValueError(f"{ply_path}: mesh has no faces")
    return ObjectInfo(
        cls=meta["cls"],
        mesh=mesh,
        convex_parts=[np.asarray(p, dtype=np.float64) for p in meta["convex_parts"]],
        mass_kg=float(meta["mass_kg"]),
        volume_m3=float(meta["volume_m3"]),
        symmetry_order=int(meta["symmetry_order"]),
        extents_m=np.asarray(meta["extents_m"], dtype=np.float64),
        up_axes=np.asarray(meta["up_axes"], dtype=np.float64).reshape(-1, 3),
        tumble=dict(meta["tumble"]),
        spec=dict(meta.get("spec") or {}),
    )
