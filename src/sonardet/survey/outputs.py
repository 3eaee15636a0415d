"""The files a survey's detections are written to, for the tools people open them in: the detection
JSON (the project's format), CSV with a JSON sidecar (QGIS, spreadsheets), GeoJSON in WGS 84 (RFC 7946)
and in the survey's CRS (GIS), the survey's soundings as a classified LAS/LAZ and the detected objects'
posed meshes as one PLY (CloudCompare). ``sonardet detect`` and the workflow's ``survey_detections``
job both write through `write_survey_outputs`.

Classified soundings (`write_classified_las`), LAS 1.4 point format 6, in the survey's working CRS
(WKT VLR), every sounding of the input once, in file order:

=====================  ============================================================================
``classification``     ASPRS code: ``2`` ground (the seabed: every sounding outside the detected
                       boxes) or ``43`` "submerged object, not otherwise specified" (ASPRS LAS 1.4
                       R15) for soundings inside a detected box (`CLASS_SEABED`, `CLASS_OBJECT`)
``object_id``          extra bytes, int32: index of the detection in the JSON's ``detections`` list
                       (and the CSV's rows), -1 on the seabed
``cls``                extra bytes, int16: index of the detection's class in the JSON's class list
                       (recorded in a ``sonardet`` VLR, record 3, as JSON), -1 on the seabed
=====================  ============================================================================

A sounding is inside a box when it lies within the box grown by `BOX_MARGIN_M` (5 cm: the fit's
tolerance) on every side; where boxes overlap, the higher-scored detection takes it. CloudCompare
shows ``classification``, ``object_id`` and ``cls`` as scalar fields.

Posed meshes (`write_posed_meshes`): each detection's class mesh (canonical frame) moved by its pose
(rotation q, translation t) into the survey's coordinates, one PLY holding them all, coloured by
class (the class specs' report colours). Vertices are float64 (PLY ``double``) in the survey CRS, so
UTM coordinates keep their millimetres and the meshes sit on the LAS soundings in CloudCompare (which
offers the same global shift for both). A detection without a pose (a box-only method) is drawn as
its box.

Frames and units: metres in the working CRS (``crs``), z up; radians.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sonardet import SCHEMA_VERSION
from sonardet.geometry import box_corners, points_in_box, quat_to_matrix
from sonardet.io.annotations import to_builtin, validate_detections
from sonardet.io.atomic import atomic_outputs, atomic_write_text, check_writable
from sonardet.io.crs import has_horizontal
from sonardet.io.export import (
    csv_sidecar_path,
    write_detections_csv,
    write_detections_geojson,
    write_detections_geojson_crs,
)
from sonardet.io.points import las as las_format

__all__ = ["BOX_MARGIN_M", "CLASS_OBJECT", "CLASS_SEABED", "OutputPaths", "SurveyMeta", "classify_soundings",
           "write_classified_las", "write_posed_meshes", "write_survey_outputs"]

#: ASPRS classification of seabed soundings (2, ground).
CLASS_SEABED = 2
#: ASPRS classification of soundings inside a detected box (43, submerged object; LAS 1.4 R15).
CLASS_OBJECT = 43
#: A sounding within this distance (m) of a detected box counts as inside it.
BOX_MARGIN_M = 0.05
_VLR_CLASSES = 3


@dataclass(frozen=True)
class OutputPaths:
    """Where a survey's detections go: ``json`` (required) and the optional ``csv`` (+ ``<csv>.json``
    sidecar), ``geojson`` (RFC 7946, WGS 84), ``geojson_crs`` (the survey's CRS), ``las`` (classified
    soundings, .las or .laz) and ``meshes`` (posed meshes, .ply)."""

    json: Path
    csv: Path | None = None
    geojson: Path | None = None
    geojson_crs: Path | None = None
    las: Path | None = None
    meshes: Path | None = None

    @classmethod
    def of(cls, **paths) -> OutputPaths:
        """Paths from keywords (str or Path; None for an output not wanted)."""
        return cls(**{k: Path(v) if v is not None else None for k, v in paths.items()})

    def files(self) -> list[Path]:
        """Every file these outputs write (the CSV's sidecar included)."""
        out = [p for p in (self.json, self.csv, self.geojson, self.geojson_crs, self.las, self.meshes) if p]
        return out + ([csv_sidecar_path(self.csv)] if self.csv else [])

    def check_suffixes(self) -> None:
        """Refuse a LAS path not ending in .las or .laz and a mesh path not ending in .ply (ValueError
        naming the option)."""
        if self.las is not None and not self.las.name.lower().endswith((".las", ".laz")):
            raise ValueError(f"--las {self.las}: the classified soundings are written as .las or .laz")
        if self.meshes is not None and not self.meshes.name.lower().endswith(".ply"):
            raise ValueError(f"--meshes {self.meshes}: the posed meshes are written as one .ply")

    def check(self, crs: str | None, have_objects: bool) -> None:
        """Refuse, before any slow work, outputs that cannot be written: bad suffixes (`check_suffixes`),
        a path that is a folder, read-only or in a folder without write permission
        (`io.atomic.check_writable`), meshes without the object models, RFC 7946 GeoJSON without a CRS.
        Raises ValueError naming the option and the fix."""
        self.check_suffixes()
        check_writable(self.files())
        if self.meshes is not None and not have_objects:
            raise ValueError(f"--meshes {self.meshes}: needs the object models (objects/<cls>.json|.ply under "
                             "--results)")
        if self.geojson is not None and not has_horizontal(crs):
            raise ValueError(f"--geojson {self.geojson}: RFC 7946 GeoJSON is in longitude/latitude and the input's "
                             f"horizontal CRS is unknown ({crs}); give it with --crs (e.g. EPSG:32610), or write the "
                             "footprints in the input's coordinates with --geojson-crs")


def classify_soundings(xyz: np.ndarray, dets: Sequence[Mapping], classes: Sequence[str],
                       margin_m: float = BOX_MARGIN_M) -> dict[str, np.ndarray]:
    """Per-sounding fields of the classified LAS (see the module doc) for soundings xyz (N, 3) (m, the
    boxes' frame) and detections ``dets`` (boxes [x, y, z, l, w, h, yaw]): ``classification`` (uint8),
    ``object_id`` (int32) and ``cls`` (int16). Boxes are taken in descending score, so where they overlap
    the higher-scored one wins.

    Each box looks only at the soundings in the square of half side ``reach`` (half the diagonal of the
    box grown by the margin: every yaw of it fits) around its centre, found in a KD-tree of the
    soundings' x, y with the Chebyshev metric (scipy ``cKDTree``, ``p=inf``), then tested exactly
    (|dx|, |dy| <= reach, then ``points_in_box``): the same soundings as a scan of the whole chunk per
    box, at the cost of one tree per chunk (the workflow's merge of benchmarks/survey.py's 10 M-sounding
    mosaic with 1,356 boxes: 11.6 s instead of 90.7 s)."""
    from scipy.spatial import cKDTree

    n = len(xyz)
    fields = {"classification": np.full(n, CLASS_SEABED, np.uint8), "object_id": np.full(n, -1, np.int32),
              "cls": np.full(n, -1, np.int16)}
    if n == 0 or len(dets) == 0:
        return fields
    index = {c: i for i, c in enumerate(classes)}
    tree = cKDTree(np.ascontiguousarray(xyz[:, :2], dtype=np.float64))
    for k in sorted(range(len(dets)), key=lambda i: -float(dets[i]["score"])):
        box = np.asarray(dets[k]["box"], dtype=np.float64)
        reach = float(np.hypot(0.5 * box[3] + margin_m, 0.5 * box[4] + margin_m))
        # The tree's radius is widened by a relative 1e-9 so that rounding cannot drop a sounding on the
        # square's edge; the exact test below decides.
        cand = np.asarray(tree.query_ball_point(box[:2], reach * (1 + 1e-9) + 1e-9, p=np.inf), dtype=np.int64)
        cand.sort()
        near = cand[(np.abs(xyz[cand, 0] - box[0]) <= reach) & (np.abs(xyz[cand, 1] - box[1]) <= reach)
                    & (fields["object_id"][cand] < 0)]
        inside = near[points_in_box(xyz[near], box, margin_m)]
        fields["classification"][inside] = CLASS_OBJECT
        fields["object_id"][inside] = k
        fields["cls"][inside] = index.get(str(dets[k]["cls"]), -1)
    return fields


def write_classified_las(path, chunks: Iterable[np.ndarray], bounds, crs: str | None, dets: Sequence[Mapping],
                         classes: Sequence[str]) -> dict:
    """Write the soundings (chunks of float64 (n, 3) m in the CRS ``crs``; every sounding of the survey
    once, in order) as a classified LAS/LAZ (see the module doc), chunk by chunk, atomically. bounds:
    (lo, hi), the (3,) minimum and maximum of all soundings (m). Returns {n_points, n_object, codes}."""
    import laspy

    codes = {"classification": {str(CLASS_SEABED): "ground (seabed)", str(CLASS_OBJECT): "submerged object"},
             "cls": {"-1": "seabed", **{str(i): c for i, c in enumerate(classes)}},
             "object_id": "index in the detections list, -1 = seabed"}
    vlr = laspy.VLR("sonardet", _VLR_CLASSES, "class codes (JSON)", json.dumps(codes).encode("utf-8"))
    extra = {"object_id": ("int32", "detection index, -1 seabed"), "cls": ("int16", "class index, -1 seabed")}
    n = n_obj = 0
    with las_format.open_writer(path, bounds=bounds, crs=crs, extra_dims=extra, vlrs=(vlr,)) as write:
        for xyz in chunks:
            fields = classify_soundings(xyz, dets, classes)
            write(xyz, fields)
            n += len(xyz)
            n_obj += int(np.count_nonzero(fields["object_id"] >= 0))
    return {"n_points": n, "n_object": n_obj, "codes": codes}


_BOX_FACES = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]]
                      + [[i, (i + 1) % 4, (i + 1) % 4 + 4] for i in range(4)]
                      + [[i, (i + 1) % 4 + 4, i + 4] for i in range(4)])


def _posed(det: Mapping, objects: Mapping) -> tuple[np.ndarray, np.ndarray]:
    """(vertices float64 (V, 3) m, faces (F, 3)) of one detection: its class mesh posed, else its box."""
    pose, obj = det.get("pose"), objects.get(str(det["cls"]))
    if pose is not None and obj is not None:
        v = np.asarray(obj.mesh.vertices, dtype=np.float64) @ quat_to_matrix(pose["q"]).T
        return v + np.asarray(pose["t"], dtype=np.float64), np.asarray(obj.mesh.faces)
    return box_corners(det["box"]), _BOX_FACES


def _rgb(colour: str) -> np.ndarray:
    """'#RRGGBB' -> float RGB in [0, 1] (grey for anything else)."""
    text = str(colour).lstrip("#")
    if len(text) != 6:
        return np.full(3, 0.6)
    return np.array([int(text[i:i + 2], 16) / 255.0 for i in (0, 2, 4)])


def write_posed_meshes(path, dets: Sequence[Mapping], objects: Mapping, colours: Mapping[str, str]) -> int:
    """Write the detections' posed meshes (see the module doc) as one binary PLY with float64 vertices
    (m, the detections' frame) and per-vertex class colours (``colours``: class -> '#RRGGBB'),
    atomically; returns the number of meshes. With no detections the PLY holds no vertex."""
    import open3d as o3d

    from sonardet.io.atomic import atomic_path

    verts, faces, rgb, base = [], [], [], 0
    for d in dets:
        v, f = _posed(d, objects)
        verts.append(v)
        faces.append(np.asarray(f, dtype=np.int64) + base)
        rgb.append(np.tile(_rgb(colours.get(str(d["cls"]), "")), (len(v), 1)))
        base += len(v)
    with atomic_path(path) as tmp:
        if not verts:
            tmp.write_text("ply\nformat ascii 1.0\ncomment sonardet posed meshes: no detections\nelement vertex 0\n"
                           "property double x\nproperty double y\nproperty double z\nelement face 0\n"
                           "property list uchar int vertex_indices\nend_header\n")
            return 0
        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.vstack(verts)),
                                         o3d.utility.Vector3iVector(np.vstack(faces).astype(np.int32)))
        mesh.vertex_colors = o3d.utility.Vector3dVector(np.vstack(rgb))
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False, print_progress=False):
            raise OSError(f"{path}: Open3D could not write the PLY")
    return len(verts)


@dataclass(frozen=True)
class SurveyMeta:
    """What the detection JSON says besides the detections: the survey's name (the JSON's ``scene``),
    the method, the source file, the working CRS of the boxes (``crs``), the CRS of the input's own
    coordinates (``input_crs``; differs when geographic input was projected to UTM) and the classes."""

    survey: str
    method: str
    source: str
    crs: str | None
    input_crs: str | None
    classes: Sequence[str] | None


def write_survey_outputs(dets: list, paths: OutputPaths, meta: SurveyMeta, *,
                         soundings: Callable[[], Iterable[np.ndarray]] | None = None, bounds=None,
                         objects: Mapping | None = None, colours: Mapping[str, str] | None = None) -> dict:
    """Write a survey's detections (boxes in ``meta.crs``, m, rad) to every path of ``paths`` (see the
    module doc) and return the JSON document (schema_version, scene = survey, method, source, crs,
    input_crs, detections; read it with ``read_detections(path, expected_scene=<survey>)``).

    soundings: a function returning the survey's soundings chunk by chunk (float64 (n, 3) m in
    ``meta.crs``), and ``bounds`` their (lo, hi), for the classified LAS; objects (class -> ObjectInfo)
    and colours (class -> '#RRGGBB') for the meshes. The files are written all or none
    (`io.atomic.atomic_outputs`): an error in any writer leaves every target as it was.
    """
    if paths.las is not None and (soundings is None or bounds is None):
        raise ValueError(f"{paths.las}: the classified soundings need the soundings and their bounds")
    # The JSON first: it is validated, so a bad detection stops before any other file is written.
    doc = {"schema_version": SCHEMA_VERSION, "scene": meta.survey, "method": meta.method, "source": str(meta.source),
           "crs": meta.crs, "input_crs": meta.input_crs, "detections": to_builtin(list(dets))}
    doc = validate_detections(doc, paths.json, meta.classes, meta.survey)
    files = paths.files()
    with atomic_outputs(files) as tmp:
        where = dict(zip(files, tmp))
        staged = OutputPaths(**{k: where[v] if v is not None else None for k, v in vars(paths).items()})
        atomic_write_text(staged.json, json.dumps(doc, indent=1, allow_nan=False) + "\n")
        dets = doc["detections"]
        if staged.csv is not None:
            write_detections_csv(staged.csv, dets, crs=meta.crs, source=str(meta.source))
        if staged.geojson is not None:
            write_detections_geojson(staged.geojson, dets, crs=meta.crs)
        if staged.geojson_crs is not None:
            write_detections_geojson_crs(staged.geojson_crs, dets, crs=meta.crs)
        if staged.las is not None:
            classes = list(meta.classes) if meta.classes else sorted({str(d["cls"]) for d in dets})
            write_classified_las(staged.las, soundings(), bounds, meta.crs, dets, classes)
        if staged.meshes is not None:
            write_posed_meshes(staged.meshes, dets, objects or {}, colours or {})
    return doc
