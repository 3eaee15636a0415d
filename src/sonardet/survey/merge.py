"""The last step of a tiled survey: merge the tiles' detections (each object once, by the tile owning its
box centre) and write them in the survey's own coordinates as JSON, CSV and GeoJSON."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

from sonardet import SCHEMA_VERSION
from sonardet.io.annotations import to_builtin, validate_detections
from sonardet.io.atomic import atomic_write_text
from sonardet.io.export import write_detections_csv, write_detections_geojson
from sonardet.survey.tiling import Tile, merge_tile_detections

__all__ = ["merge_survey_detections", "write_survey_detections"]


def merge_survey_detections(index: dict, tiles: list[Tile], per_tile: Mapping, dup_dist_m: float = 0.5):
    """Merge the detections of a survey's tiles (tile id -> list of detections, boxes in the survey's
    coordinates, m) with `merge_tile_detections`: each object reported once, by the tile owning its box
    centre, sorted by descending score.

    Every tile of the index that holds points must be in `per_tile` (an empty list if it found
    nothing) and no other: a lost or foreign tile raises ValueError, so nothing is merged silently
    from a partial run. Returns (detections, rows), rows one per tile of the plan: {tile, n_points,
    n_detections, n_kept (detections the tile owns before the cross-tile duplicate check)}.
    """
    expected = {t["id"] for t in index["tiles"] if t["file"] is not None}
    got = set(per_tile)
    if got != expected:
        lost, extra = sorted(expected - got), sorted(got - expected)
        raise ValueError(f"survey {index.get('survey')!r}: tile detections do not match the tile index "
                         f"(missing: {', '.join(lost) or '-'}; not in the index or empty: {', '.join(extra) or '-'})")
    by_id = {t.id: t for t in tiles}
    rows = []
    for t in index["tiles"]:
        dets = per_tile.get(t["id"], [])
        tile = by_id[t["id"]]
        rows.append({"tile": t["id"], "n_points": t["n_points"], "n_detections": len(dets),
                     "n_kept": sum(bool(tile.owns(d["box"][0], d["box"][1])) for d in dets)})
    return merge_tile_detections(dict(per_tile), tiles, dup_dist_m), rows


def write_survey_detections(dets: list, json_path, csv_path=None, geojson_path=None, *, survey: str,
                            method: str, source: str, crs: str | None, classes=None) -> dict:
    """Write a survey's merged detections (boxes in the survey's coordinates, m, rad) as the JSON of
    ``sonardet detect`` (schema_version, scene, method, source, crs, detections; `scene` is the survey's
    name: read it with ``read_detections(path, expected_scene=<survey>)``), and optionally as CSV and
    GeoJSON (`sonardet.io.export`, CRS named). Atomic writes; returns the JSON document."""
    doc = {"schema_version": SCHEMA_VERSION, "scene": survey, "method": method, "source": str(source), "crs": crs,
           "detections": to_builtin(list(dets))}
    doc = validate_detections(doc, json_path, classes, survey)
    atomic_write_text(json_path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    frame = f"{crs} metres" if crs else "the survey file's coordinates (metres, CRS unknown)"
    if csv_path is not None:
        write_detections_csv(csv_path, doc["detections"],
                             origin_note=f"coordinates: {frame}, as in {Path(source).name}; yaw_rad about +z")
    if geojson_path is not None:
        write_detections_geojson(geojson_path, doc["detections"], crs=crs)
    return doc
