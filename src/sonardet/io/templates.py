"""Template scan files: ``templates/{cls}.npz``, every view of one object class scanned by the sensor model
(``sonardet.sim.templates`` makes them, the model-based detector reads them).

File (``numpy.savez_compressed``): ``schema_version``; ``cls``; per point ``xyz`` (K, 3) float64 (the
object's canonical frame, metres), ``view``, ``ping``, ``beam``; per view ``yaw_rad`` (rad),
``direction`` ('x' or 'y'), ``offset_m`` (m), ``pose_t`` (V, 3) (m), ``pose_q`` (V, 4) (w, x, y, z);
``scan_params``, a JSON string (altitude and sensor settings). Readers reject other schema versions.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np

from sonardet import SCHEMA_VERSION
from sonardet.io.artifacts import FileReadError, read_npz, reading
from sonardet.io.atomic import atomic_path

__all__ = ["TemplateViews", "read_templates", "write_templates"]


@dataclass
class TemplateViews:
    """All views of one class. Per point: xyz (canonical frame, m), view index, ping, beam.
    Per view: yaw (rad), line direction ('x' or 'y'), across-track offset of the object from the
    track (m, positive = starboard), pose (t, q) of the object in the view's scene frame."""

    cls: str
    xyz: np.ndarray
    view: np.ndarray
    ping: np.ndarray
    beam: np.ndarray
    yaw_rad: np.ndarray
    direction: np.ndarray
    offset_m: np.ndarray
    pose_t: np.ndarray
    pose_q: np.ndarray
    scan_params: dict

    def points(self, view: int) -> np.ndarray:
        """Canonical-frame points (K,3) of one view."""
        return self.xyz[self.view == view]

    @property
    def n_views(self) -> int:
        """Number of views."""
        return len(self.yaw_rad)


#: The entries of a template file (besides schema_version).
_TEMPLATE_ENTRIES = ("cls", "xyz", "view", "ping", "beam", "yaw_rad", "direction", "offset_m", "pose_t", "pose_q",
                     "scan_params")


def write_templates(path: str | os.PathLike, tv: TemplateViews) -> None:
    """Write template views to an .npz (atomic): points in the canonical frame (m), per-view yaw (rad),
    offsets and poses (m), scan parameters as JSON (see the module docstring)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(
                fh, schema_version=SCHEMA_VERSION, cls=tv.cls, xyz=tv.xyz, view=tv.view, ping=tv.ping,
                beam=tv.beam, yaw_rad=tv.yaw_rad, direction=tv.direction, offset_m=tv.offset_m,
                pose_t=tv.pose_t, pose_q=tv.pose_q, scan_params=json.dumps(tv.scan_params),
            )


def read_templates(path: str | os.PathLike) -> TemplateViews:
    """Read template views written by :func:`write_templates` (canonical frame, metres and radians);
    rejects other schema versions, truncated or damaged files and missing entries
    (``sonardet.io.artifacts.FileReadError``, a ValueError naming the file and the entry)."""
    what = "template scan file"
    z = read_npz(path, what, required=("schema_version",))
    version = int(z["schema_version"])
    if version != SCHEMA_VERSION:
        raise FileReadError(f"{path}: schema_version {version} is not {SCHEMA_VERSION}; rebuild the templates "
                            "(delete the file and rerun the step that writes it)")
    missing = [k for k in _TEMPLATE_ENTRIES if k not in z]
    if missing:
        raise FileReadError(f"{path}: no entry {', '.join(map(repr, missing))}; not a complete {what}: delete it and "
                            "rerun the step that writes it")
    with reading(path, what, member="scan_params"):
        scan_params = json.loads(str(z["scan_params"]))
    return TemplateViews(
        cls=str(z["cls"]), xyz=z["xyz"], view=z["view"], ping=z["ping"], beam=z["beam"],
        yaw_rad=z["yaw_rad"], direction=z["direction"], offset_m=z["offset_m"], pose_t=z["pose_t"],
        pose_q=z["pose_q"], scan_params=scan_params,
    )
