"""The synthetic dataset in OpenPCDet's custom-dataset layout (docs/CUSTOM_DATASET_TUTORIAL.md of
OpenPCDet), so any OpenPCDet detector (PointPillars, SECOND, PV-RCNN, CenterPoint, ...) trains on our
scenes::

    <out>/points/<scene>.npy     float32 (N, 4): x, y, z (m, the scene's local frame) and one feature
    <out>/labels/<scene>.txt     one box per line: x y z dx dy dz heading class_name
    <out>/ImageSets/train.txt    scene ids of our `train` split
    <out>/ImageSets/val.txt      scene ids of our `dev` split (the development scenes: every choice)
    <out>/ImageSets/test.txt     scene ids of our `test` split (final evaluation only)
    <out>/ImageSets/train_<f>.txt the nested training fractions, when given
    <out>/sonardet_dataset.json  classes, per-scene origins, split sizes, the feature, the frame
    <out>/custom_dataset.yaml    the dataset-config keys to merge into OpenPCDet's custom_dataset.yaml
                                 (CLASS_NAMES, POINT_CLOUD_RANGE, POINT_FEATURE_ENCODING, DATA_SPLIT)

Boxes: OpenPCDet's unified box is ours: centre x, y, z, extents dx (along the heading), dy, dz, heading
about +z in radians (here wrapped to [-pi, pi)). Labels hold the visible objects (``visible: true`` in
the scene JSON, those the evaluation scores); an object without a sounding cannot be learned.

Frame: float32 needs small coordinates, so each scene is shifted by its local origin
(``sonardet.io.origin.LocalFrame.from_points``: x, y minimum floored to a metre, z = 0); the scenes the
simulator writes are local already (origin 0, 0, 0). The origin of every scene is in
``sonardet_dataset.json``. z keeps the scene's vertical datum (elevation, the seabed near -11.5 m).

Feature (4th column): ``zero`` (default; OpenPCDet's ``intensity`` slot, MBES scenes have none) or
``beam``, the beam's distance from the swath centre in [0, 1] (|beam - c| / c, c = (n_beams - 1) / 2 from
the scene's beams), which carries the across-track incidence a multibeam's noise depends on.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from sonardet.io.atomic import atomic_path, atomic_write_text
from sonardet.io.origin import LocalFrame
from sonardet.io.scenes import read_scene, read_scene_points

__all__ = ["FEATURES", "IMAGE_SETS", "export_openpcdet", "read_openpcdet_labels"]

#: Our split -> OpenPCDet's ImageSets file.
IMAGE_SETS = {"train": "train", "dev": "val", "test": "test"}
#: The 4th point column: name -> description.
FEATURES = {"zero": "0.0 (OpenPCDet's intensity slot)", "beam": "beam distance from the swath centre, 0..1"}


def _feature(points: Mapping[str, np.ndarray], feature: str, where: str) -> np.ndarray:
    """The 4th column of a scene's points (see the module doc)."""
    n = len(points["xyz"])
    if feature == "zero":
        return np.zeros(n, dtype=np.float32)
    if "beam" not in points:
        raise ValueError(f"{where}: no 'beam' array for --feature beam; use --feature zero")
    beam = points["beam"].astype(np.float64)
    centre = max((float(beam.max()) - float(beam.min())) / 2.0, 0.5)
    return (np.abs(beam - float(beam.min()) - centre) / centre).astype(np.float32)


def _label_lines(doc: dict, origin: np.ndarray) -> list[str]:
    """The label file's lines of one scene: visible objects, boxes shifted by the local origin."""
    lines = []
    for o in doc["objects"]:
        if not o.get("visible", True):
            continue
        x, y, z, l, w, h, yaw = (float(v) for v in o["box"])
        heading = (yaw + math.pi) % (2.0 * math.pi) - math.pi
        vals = (x - origin[0], y - origin[1], z - origin[2], l, w, h, heading)
        lines.append(" ".join(repr(float(v)) for v in vals) + f" {o['cls']}")
    return lines


def _range(lo: np.ndarray, hi: np.ndarray, voxel_m: float = 0.1, voxel_z_m: float = 0.15) -> list[float]:
    """POINT_CLOUD_RANGE covering [lo, hi] that OpenPCDet's voxel detectors accept: x/y extents a multiple
    of 16 voxels, z extent 40 voxels (voxel 0.1 m, 0.15 m in z); z range centred on the data."""
    step = 16 * voxel_m
    x0, y0 = (math.floor(v / step) * step for v in lo[:2])
    size = max(math.ceil((hi[0] - x0) / step), math.ceil((hi[1] - y0) / step)) * step
    zc, zh = 0.5 * (lo[2] + hi[2]), 20 * voxel_z_m
    return [round(float(v), 6) for v in (x0, y0, zc - zh, x0 + size, y0 + size, zc + zh)]


def export_openpcdet(scene_dir, splits: Mapping[str, Sequence[str]], out_dir, *, classes: Sequence[str],
                     feature: str = "zero", progress: Iterable | None = None) -> dict:
    """Write the scenes of ``splits`` (our split name -> scene ids; ``train``, ``dev``, ``test`` and
    ``train_<f>``) from ``scene_dir`` (``<scene>.npz`` + ``<scene>.json``) in OpenPCDet's layout under
    ``out_dir`` (see the module doc); every file atomically. ``progress``: a wrapper of the scene
    iterable (e.g. a progress bar), called as ``progress(ids)``. Returns the ``sonardet_dataset.json``
    document. Raises ValueError for an unknown feature, a missing scene or a class outside ``classes``."""
    if feature not in FEATURES:
        raise ValueError(f"feature must be one of {sorted(FEATURES)}, got {feature!r}")
    scene_dir, out = Path(scene_dir), Path(out_dir)
    ids = sorted({s for v in splits.values() for s in v})
    missing = [s for s in ids if not (scene_dir / f"{s}.npz").is_file() or not (scene_dir / f"{s}.json").is_file()]
    if missing:
        raise ValueError(f"{scene_dir}: scene files missing for {', '.join(missing[:5])}"
                         f"{' ...' if len(missing) > 5 else ''} ({len(missing)} scenes); simulate them first")
    origins, lo, hi = {}, np.full(3, np.inf), np.full(3, -np.inf)
    for sid in (progress(ids) if progress is not None else ids):
        points = read_scene_points(scene_dir / f"{sid}.npz")
        doc = read_scene(scene_dir / f"{sid}.json", classes, sid)
        frame = LocalFrame.from_points(points["xyz"])
        local = frame.to_local(points["xyz"], dtype=np.float32)
        arr = np.column_stack([local, _feature(points, feature, str(scene_dir / f"{sid}.npz"))]).astype(np.float32)
        with atomic_path(out / "points" / f"{sid}.npy") as tmp:
            np.save(tmp, arr)
        lines = _label_lines(doc, frame.origin)
        atomic_write_text(out / "labels" / f"{sid}.txt", "".join(f"{line}\n" for line in lines))
        origins[sid] = [float(v) for v in frame.origin]
        lo, hi = np.minimum(lo, local.min(0)), np.maximum(hi, local.max(0))
    sets = {IMAGE_SETS.get(name, name): list(v) for name, v in splits.items()}
    for name, v in sets.items():
        atomic_write_text(out / "ImageSets" / f"{name}.txt", "".join(f"{s}\n" for s in v))
    info = {"format": "openpcdet_custom", "classes": list(classes), "feature": feature,
            "feature_meaning": FEATURES[feature], "image_sets": {k: len(v) for k, v in sets.items()},
            "split_names": {name: IMAGE_SETS.get(name, name) for name in splits},
            "frame": "points and labels: scene frame (x east, y north, z up, m) minus the scene's origin",
            "origins": origins}
    atomic_write_text(out / "sonardet_dataset.json", json.dumps(info, indent=1) + "\n")
    _write_dataset_yaml(out / "custom_dataset.yaml", classes, feature, _range(lo, hi), "test" in splits)
    return info


def _write_dataset_yaml(path: Path, classes: Sequence[str], feature: str, pc_range: list[float], has_test: bool):
    """The dataset-config keys of this export for OpenPCDet's custom_dataset.yaml."""
    import yaml

    feat = "intensity" if feature == "zero" else feature
    doc = {"DATASET": "CustomDataset", "CLASS_NAMES": list(classes), "POINT_CLOUD_RANGE": pc_range,
           "DATA_SPLIT": {"train": "train", "test": "val"},
           "INFO_PATH": {"train": ["custom_infos_train.pkl"], "test": ["custom_infos_val.pkl"]},
           "POINT_FEATURE_ENCODING": {"encoding_type": "absolute_coordinates_encoding",
                                      "used_feature_list": ["x", "y", "z", feat],
                                      "src_feature_list": ["x", "y", "z", feat]},
           "MAP_CLASS_TO_KITTI": {c: "Car" for c in classes}}
    head = ("# Keys for OpenPCDet's tools/cfgs/dataset_configs/custom_dataset.yaml, written by sonardet export-dataset.\n"
            "# ImageSets/val.txt is sonardet's dev split" + ("; test.txt the final test split.\n" if has_test else ".\n"))
    atomic_write_text(path, head + yaml.safe_dump(doc, sort_keys=False))


def read_openpcdet_labels(path) -> list[tuple[list[float], str]]:
    """The boxes of an OpenPCDet label file: [(box [x, y, z, dx, dy, dz, heading] (m, rad), class name)]."""
    out = []
    for k, line in enumerate(Path(path).read_text().splitlines(), 1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 8:
            raise ValueError(f"{path} line {k}: expected 'x y z dx dy dz heading class', got {line!r}")
        out.append(([float(v) for v in parts[:7]], parts[7]))
    return out
