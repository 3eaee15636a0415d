"""Detections for GIS and spreadsheets: CSV (with a JSON sidecar) and GeoJSON exports (the JSON of
`sonardet.io.annotations` stays the project's own format).

Coordinates are written as they come (the detections' frame, e.g. the survey CRS: UTM easting,
northing, elevation in metres) with Python's shortest round-trip float repr, so a float64 value reads
back bit-identical: no rounding to centimetres, which would cost up to 5 mm on UTM coordinates.
Every writer is atomic (temporary file in the target directory, then `os.replace`).

CSV (`write_detections_csv`): a plain table that QGIS's delimited-text import, pandas and spreadsheets
read without options: a header line, then one row per detection with columns
``cls, x, y, z, l, w, h, yaw_rad, score`` (box centre and extents in metres, yaw in radians about +z,
`l` along the yaw direction), ``lon, lat`` (WGS 84 degrees of the box centre, EPSG:4326, when the CRS is
known; QGIS: X field lon, Y field lat) and ``qw, qx, qy, qz`` (the pose quaternion, scalar first) when
any detection has a pose (empty cells for those without). No comment lines: what the columns mean, the
CRS and the source go into a JSON sidecar ``<name>.csv.json`` (`csv_sidecar_path`).

GeoJSON, two flavours:

* `write_detections_geojson`: RFC 7946, the GeoJSON every web map and GIS reads: positions in WGS 84
  longitude, latitude (degrees), no ``crs`` member. One Polygon per detection, the box's footprint (its
  bottom rectangle, rotated by yaw) projected corner by corner from the boxes' CRS with pyproj, exterior
  ring counter-clockwise and closed; properties cls, score, z (box centre elevation, m), h, l, w (m),
  yaw (rad, about +z of the boxes' CRS grid), and accepted when known. Needs the boxes' CRS.
* `write_detections_geojson_crs`: the same features in the boxes' own CRS (e.g. UTM metres), the CRS
  named in a top-level ``crs`` member in the GeoJSON 2008 form (``{"type": "name", "properties":
  {"name": "urn:ogc:def:crs:EPSG::32610"}}``) that GDAL/OGR and QGIS read; RFC 7946 dropped it, so strict
  RFC 7946 readers take these coordinates for degrees: use it for GIS work in the survey's CRS.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import re
from pathlib import Path

import numpy as np

from .. import SCHEMA_VERSION
from ..geometry import box_corners
from .atomic import atomic_write_text
from .crs import LONLAT_CRS, has_horizontal, lonlat_of

log = logging.getLogger(__name__)

__all__ = ["CSV_COLUMNS", "LONLAT_COLUMNS", "POSE_COLUMNS", "crs_urn", "csv_sidecar_path", "write_detections_csv",
           "write_detections_geojson", "write_detections_geojson_crs"]

#: Columns of every CSV row (box in metres, yaw in radians).
CSV_COLUMNS = ("cls", "x", "y", "z", "l", "w", "h", "yaw_rad", "score")
#: WGS 84 longitude and latitude (degrees) of the box centre, present when the CRS is known.
LONLAT_COLUMNS = ("lon", "lat")
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


def csv_sidecar_path(path) -> Path:
    """The JSON sidecar of a CSV export: ``<path>.json`` (``detections.csv`` -> ``detections.csv.json``)."""
    p = Path(path)
    return p.with_name(p.name + ".json")


def _lonlat(boxes: list[list[float]], crs: str | None):
    """WGS 84 (lon, lat) arrays of the box centres (degrees), or None without a CRS."""
    if crs is None or not boxes:
        return None
    xy = np.asarray([b[:2] for b in boxes], dtype=np.float64)
    return lonlat_of(xy[:, 0], xy[:, 1], crs)


def write_detections_csv(path, dets, crs: str | None = None, source: str | None = None, sidecar: bool = True) -> dict:
    """Write detections (dicts {cls, box [x,y,z,l,w,h,yaw], score, pose {t, q} (optional)}; metres and
    radians, in the frame the boxes are in, the CRS ``crs``) as CSV to `path` (see the module doc), and
    with ``sidecar`` its JSON sidecar (`csv_sidecar_path`: columns with units, crs, source); atomically.
    lon/lat columns (WGS 84 degrees of the box centres) are written when ``crs`` places positions on the
    globe (a projected or geographic horizontal part; pyproj).
    Returns the sidecar document. Raises ValueError for a box that is not 7 finite numbers."""
    dets = list(dets)
    boxes = [_box(d, k) for k, d in enumerate(dets)]
    with_pose = any(d.get("pose") is not None for d in dets)
    georef = has_horizontal(crs)
    lonlat = _lonlat(boxes, crs) if georef else None
    columns = CSV_COLUMNS + (LONLAT_COLUMNS if georef else ()) + (POSE_COLUMNS if with_pose else ())
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for k, d in enumerate(dets):
        row = [str(d["cls"])] + [_num(v) for v in boxes[k]] + [_num(d["score"])]
        if georef:
            row += [_num(lonlat[0][k]), _num(lonlat[1][k])]
        if with_pose:
            pose = d.get("pose")
            row += [_num(v) for v in pose["q"]] if pose is not None else [""] * 4
        w.writerow(row)
    frame = f"{crs}" if crs else "the input's coordinates (CRS unknown)"
    meta = {"schema_version": SCHEMA_VERSION, "file": Path(path).name, "source": source, "crs": crs,
            "lonlat_crs": LONLAT_CRS if georef else None, "n_rows": len(dets),
            "columns": {c: _COLUMN_DOC[c].format(frame=frame) for c in columns}}
    atomic_write_text(path, buf.getvalue())
    if sidecar:
        atomic_write_text(csv_sidecar_path(path), json.dumps(meta, indent=1) + "\n")
    return meta


_COLUMN_DOC = {
    "cls": "object class", "x": "box centre x (m, {frame})", "y": "box centre y (m, {frame})",
    "z": "box centre z (m, up)", "l": "box length along yaw (m)", "w": "box width (m)", "h": "box height (m)",
    "yaw_rad": "box yaw (rad, counter-clockwise about +z from the x axis of {frame})",
    "score": "detection score (0..1)", "lon": "box centre longitude (degrees, WGS 84, EPSG:4326)",
    "lat": "box centre latitude (degrees, WGS 84, EPSG:4326)", "qw": "pose quaternion w (scalar)",
    "qx": "pose quaternion x", "qy": "pose quaternion y", "qz": "pose quaternion z",
}


def crs_urn(crs: str | None) -> str | None:
    """OGC URN of an "EPSG:<code>" CRS string ("EPSG:32610" -> "urn:ogc:def:crs:EPSG::32610"; of the
    horizontal part of a compound "EPSG:32610+5703", since GeoJSON positions are 2-D); a URN is returned
    as is; None (or any other spelling, e.g. WKT) gives None."""
    if crs is None:
        return None
    text = crs.strip()
    if text.lower().startswith("urn:ogc:def:crs:"):
        return text
    m = re.fullmatch(r"(?i)epsg\s*:\s*(\d+)(\s*\+\s*\d+)?", text)
    return f"urn:ogc:def:crs:EPSG::{int(m.group(1))}" if m else None


def _features(dets, transform=None) -> list[dict]:
    """GeoJSON Features of the box footprints (see the module doc); `transform(x, y) -> (x', y')` maps
    the corners (e.g. to lon/lat), None keeps them."""
    features = []
    for k, d in enumerate(dets):
        box = _box(d, k)
        ring = box_corners(box)[:4, :2]
        ring = np.vstack([ring, ring[:1]])
        if transform is not None:
            x, y = transform(ring[:, 0], ring[:, 1])
            ring = np.stack([x, y], axis=1)
            ring[-1] = ring[0]
            area2 = float(np.sum(ring[:-1, 0] * ring[1:, 1] - ring[1:, 0] * ring[:-1, 1]))
            if area2 < 0:  # a left-handed CRS (e.g. southing/westing axes) flips the ring: RFC 7946 wants CCW
                ring = ring[::-1]
        coords = [[float(x), float(y)] for x, y in ring]
        props = {"cls": str(d["cls"]), "score": float(d["score"]), "z": box[2], "h": box[5], "l": box[3],
                 "w": box[4], "yaw": box[6]}
        if "accepted" in (d.get("extras") or {}):
            props["accepted"] = bool(d["extras"]["accepted"])
        features.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [coords]},
                         "properties": props})
    return features


def write_detections_geojson(path, dets, crs: str) -> dict:
    """Write detections (as for `write_detections_csv`, boxes in the CRS ``crs``) as RFC 7946 GeoJSON to
    `path`, atomically: footprint polygons in WGS 84 longitude, latitude (degrees; pyproj, always_xy),
    no ``crs`` member; returns the document. Raises ValueError without a CRS (the positions cannot be
    placed on the globe: give the input's CRS, or use `write_detections_geojson_crs`)."""
    if not has_horizontal(crs):
        raise ValueError(f"{path}: RFC 7946 GeoJSON is in longitude/latitude and the detections' horizontal CRS "
                         f"is unknown ({crs}); "
                         "give the input's CRS (--crs), or write the GeoJSON in the input's coordinates instead")
    doc = {"type": "FeatureCollection", "features": _features(dets, lambda x, y: lonlat_of(x, y, crs))}
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return doc


def write_detections_geojson_crs(path, dets, crs: str | None = None) -> dict:
    """Write detections (as for `write_detections_csv`) as a GeoJSON FeatureCollection of their box
    footprints in the boxes' own frame to `path`, atomically; returns the document written.

    Each feature is a Polygon: the bottom rectangle of the box [x, y, z, l, w, h, yaw] (metres, yaw in
    radians about +z) in the boxes' frame, counter-clockwise and closed; properties cls, score, z
    (box centre, m), h, l, w (m), yaw (rad), and accepted when the detection's extras carry it.
    crs: the frame of the boxes, e.g. "EPSG:32610"; named in a top-level `crs` member (see the module
    doc). A CRS that is not an EPSG code or URN is left out with a warning.
    """
    doc = {"type": "FeatureCollection"}
    urn = crs_urn(crs)
    if urn is not None:
        doc["crs"] = {"type": "name", "properties": {"name": urn}}
    elif crs is not None:
        log.warning("%s: CRS %r is not an EPSG code; the GeoJSON names no CRS", path, crs)
    doc["features"] = _features(dets)
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return doc
