"""Detections for GIS and spreadsheets: CSV and GeoJSON exports (the JSON of `sonardet.io.annotations`
stays the project's own format).

Coordinates are written as they come (the detections' frame, e.g. the survey CRS: UTM easting,
northing, elevation in metres) with Python's shortest round-trip float repr, so a float64 value reads
back bit-identical: no rounding to centimetres, which would cost up to 5 mm on UTM coordinates.
Both writers are atomic (temporary file in the target directory, then `os.replace`).

CSV (`write_detections_csv`): one row per detection with columns
``cls, x, y, z, l, w, h, yaw_rad, score`` (box centre and extents in metres, yaw in radians about +z,
`l` along the yaw direction) plus ``qw, qx, qy, qz`` (the pose quaternion, scalar first) when any
detection has a pose (empty cells for those without). An optional first line ``# <note>`` says
which frame the coordinates are in (pandas: ``read_csv(path, comment="#")``).

GeoJSON (`write_detections_geojson`): a FeatureCollection with one Polygon per detection, the box's
footprint (its bottom rectangle, rotated by yaw, counter-clockwise, closed) in x/y, and the
properties cls, score, z (box centre elevation, m), h (box height, m), l, w (m), yaw (rad).
When the CRS is known it is named in a top-level ``crs`` member in the GeoJSON 2008 form
(``{"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::32610"}}``), which GDAL/OGR and
QGIS read; RFC 7946 dropped that member and assumes WGS 84 longitude/latitude, so a strict RFC 7946
reader ignores it and projected coordinates have to be declared to it by hand.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import re

import numpy as np

from ..geometry import box_corners
from .atomic import atomic_write_text

log = logging.getLogger(__name__)

__all__ = ["CSV_COLUMNS", "POSE_COLUMNS", "crs_urn", "write_detections_csv", "write_detections_geojson"]

#: Columns of every CSV row (box in metres, yaw in radians).
CSV_COLUMNS = ("cls", "x", "y", "z", "l", "w", "h", "yaw_rad", "score")
#: Pose quaternion columns (scalar first), present when any detection has a pose.
POSE_COLUMNS = ("qw", "qx", "qy", "qz")


def _num(v) -> str:
    """Shortest string that reads back to the identical float64; refuses NaN/Inf."""
    f = float(v)
    if not math.isfinite(f):
        raise ValueError(f"non-finite value {f!r} in a detection; detections must be finite")
    return repr(f)


def _box(det, k: int) -> list[float]:
    try:
        box = [float(v) for v in det["box"]]
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"detection {k}: needs a 'box' of 7 numbers [x, y, z, l, w, h, yaw] ({exc})") from None
    if len(box) != 7 or not all(math.isfinite(v) for v in box):
        raise ValueError(f"detection {k}: box must be 7 finite numbers [x, y, z, l, w, h, yaw], got {det['box']!r}")
    return box


def write_detections_csv(path, dets, origin_note: str | None = None) -> None:
    """Write detections (dicts {cls, box [x,y,z,l,w,h,yaw], score, pose {t, q} (optional)}; metres and
    radians, in the frame the boxes are in) as CSV to `path`, atomically.

    origin_note: a one-line note on the coordinates' frame (e.g. "coordinates: EPSG:32610 metres, as
    in survey.xyz"), written as a first line starting with "# "; None writes no note. Raises
    ValueError for a box that is not 7 finite numbers or a note with a line break.
    """
    dets = list(dets)
    with_pose = any(d.get("pose") is not None for d in dets)
    buf = io.StringIO()
    if origin_note is not None:
        if "\n" in origin_note or "\r" in origin_note:
            raise ValueError("origin_note must be a single line")
        buf.write(f"# {origin_note}\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS + (POSE_COLUMNS if with_pose else ()))
    for k, d in enumerate(dets):
        row = [str(d["cls"])] + [_num(v) for v in _box(d, k)] + [_num(d["score"])]
        if with_pose:
            pose = d.get("pose")
            row += [_num(v) for v in pose["q"]] if pose is not None else [""] * 4
        w.writerow(row)
    atomic_write_text(path, buf.getvalue())


def crs_urn(crs: str | None) -> str | None:
    """OGC URN of an "EPSG:<code>" CRS string ("EPSG:32610" -> "urn:ogc:def:crs:EPSG::32610"); a URN is
    returned as is; None (or any other spelling, e.g. WKT) gives None."""
    if crs is None:
        return None
    text = crs.strip()
    if text.lower().startswith("urn:ogc:def:crs:"):
        return text
    m = re.fullmatch(r"(?i)epsg\s*:\s*(\d+)", text)
    return f"urn:ogc:def:crs:EPSG::{int(m.group(1))}" if m else None


def write_detections_geojson(path, dets, crs: str | None = None) -> dict:
    """Write detections (as for `write_detections_csv`) as a GeoJSON FeatureCollection of their box
    footprints to `path`, atomically; returns the document written.

    Each feature is a Polygon: the bottom rectangle of the box [x, y, z, l, w, h, yaw] (metres, yaw in
    radians about +z) in the boxes' frame, counter-clockwise and closed; properties cls, score, z
    (box centre, m), h, l, w (m), yaw (rad), and accepted when the detection's extras carry it.
    crs: the frame of the boxes, e.g. "EPSG:32610"; named in a top-level `crs` member (see the module
    doc). A CRS that is not an EPSG code or URN is left out with a warning.
    """
    features = []
    for k, d in enumerate(dets):
        box = _box(d, k)
        ring = box_corners(box)[:4, :2]
        coords = [[float(x), float(y)] for x, y in np.vstack([ring, ring[:1]])]
        props = {"cls": str(d["cls"]), "score": float(d["score"]), "z": box[2], "h": box[5], "l": box[3],
                 "w": box[4], "yaw": box[6]}
        if "accepted" in (d.get("extras") or {}):
            props["accepted"] = bool(d["extras"]["accepted"])
        features.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [coords]},
                         "properties": props})
    doc = {"type": "FeatureCollection"}
    urn = crs_urn(crs)
    if urn is not None:
        doc["crs"] = {"type": "name", "properties": {"name": urn}}
    elif crs is not None:
        log.warning("%s: CRS %r is not an EPSG code; the GeoJSON names no CRS", path, crs)
    doc["features"] = features
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return doc
