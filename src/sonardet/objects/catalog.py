"""Object metadata and the on-disk form of an object: `objects/{cls}.ply` + `objects/{cls}.json`."""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from .. import SCHEMA_VERSION
from ..geometry import box_from_points, quat_multiply, quat_to_matrix, yaw_of_matrix
from ..io.artifacts import FileReadError, read_json_file, reading, rebuild_hint
from ..io.atomic import atomic_outputs, atomic_write_text
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


def mesh_file_check(ply_path) -> dict:
    """How a mesh file reads back: {watertight (both readers agree it is closed), watertight_trimesh
    (trimesh.load with its default vertex merging), watertight_open3d (Open3D's reader and
    `is_watertight`: edge- and vertex-manifold, no self-intersection), n_vertices, n_faces} (counts
    after trimesh's merge)."""
    import open3d as o3d

    mesh = trimesh.load(ply_path, force="mesh")
    o3d_mesh = o3d.io.read_triangle_mesh(str(ply_path))
    tm_ok, o3d_ok = bool(mesh.is_watertight), bool(o3d_mesh.is_watertight())
    return {"watertight": tm_ok and o3d_ok, "watertight_trimesh": tm_ok, "watertight_open3d": o3d_ok,
            "n_vertices": int(len(mesh.vertices)), "n_faces": int(len(mesh.faces))}


def _write_ply(path, mesh: trimesh.Trimesh) -> None:
    """The mesh as binary PLY with float64 vertices (Open3D's writer; trimesh's writes float32, which
    moves vertices by up to 6e-8 m and can make near-coplanar facets cross)."""
    import open3d as o3d

    o3d_mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.array(mesh.vertices, dtype=np.float64)),
                                         o3d.utility.Vector3iVector(np.array(mesh.faces, dtype=np.int32)))
    if not o3d.io.write_triangle_mesh(str(path), o3d_mesh, write_ascii=False, compressed=False,
                                      write_vertex_normals=False, write_vertex_colors=False,
                                      write_triangle_uvs=False, print_progress=False):
        raise OSError(f"{path}: Open3D could not write the mesh")


def write_object(model: ObjectModel, density_kg_m3: float, ply_path, json_path) -> dict:
    """Write the mesh (binary PLY, float64 vertices, canonical frame, m) and its metadata (JSON), both or
    neither (`sonardet.io.atomic.atomic_outputs`). The metadata's `watertight` (and
    `watertight_trimesh`, `watertight_open3d`) are measured on the PLY as written and read back
    (`mesh_file_check`); a mesh that does not read back closed is written with a warning. Returns the
    metadata."""
    meta = metadata(model, density_kg_m3)
    with atomic_outputs([ply_path, json_path]) as (ply_tmp, json_tmp):
        _write_ply(ply_tmp, model.mesh)
        check = mesh_file_check(ply_tmp)
        meta.update(watertight=check["watertight"], watertight_trimesh=check["watertight_trimesh"],
                    watertight_open3d=check["watertight_open3d"])
        if not check["watertight"]:
            warnings.warn(f"{ply_path}: the {model.cls} mesh does not read back watertight (trimesh "
                          f"{check['watertight_trimesh']}, Open3D {check['watertight_open3d']}); its volume and "
                          "mass are unreliable", stacklevel=2)
        atomic_write_text(json_tmp, json.dumps(meta, indent=1))
    return meta


def read_object(json_path, ply_path=None) -> ObjectInfo:
    """Read an object written by :func:`write_object` (PLY beside the JSON unless given). A missing,
    truncated or damaged file raises an error naming it (``sonardet.io.artifacts.FileReadError``, a
    ValueError, or FileNotFoundError) with the fix."""
    json_path = Path(json_path)
    ply_path = Path(ply_path) if ply_path else json_path.with_suffix(".ply")
    meta = read_json_file(json_path, "object metadata file")
    if not isinstance(meta, dict) or meta.get("schema_version") != SCHEMA_VERSION:
        version = meta.get("schema_version") if isinstance(meta, dict) else None
        raise FileReadError(
            f"{json_path}: schema_version {version!r} is not {SCHEMA_VERSION}; "
            "rebuild it with `snakemake results/objects/<cls>.json`"
        )
    missing = [k for k in _OBJECT_KEYS if k not in meta]
    if missing:
        raise FileReadError(f"{json_path}: no {', '.join(missing)} (written by an older sonardet, or damaged); "
                            f"{rebuild_hint(json_path)}")
    with reading(ply_path, "object mesh (PLY)"):
        mesh = trimesh.load(ply_path, force="mesh", process=False)
    if len(mesh.faces) == 0:
        raise FileReadError(f"{ply_path}: mesh has no faces; {rebuild_hint(ply_path)}")
    with reading(json_path, "object metadata file"):
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


#: Keys of an object's metadata that `read_object` needs.
_OBJECT_KEYS = ("cls", "convex_parts", "mass_kg", "volume_m3", "symmetry_order", "extents_m", "up_axes", "tumble")
