"""The last step of a tiled survey: merge the tiles' detections (each object once, by the tile owning its
box centre) and write them in the survey's coordinates (JSON, CSV, GeoJSON, classified LAS, meshes)."""

from __future__ import annotations

from collections.abc import Mapping

from sonardet.survey.outputs import OutputPaths, SurveyMeta, write_survey_outputs
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
                            method: str, source: str, crs: str | None, classes=None, input_crs: str | None = None,
                            geojson_crs_path=None, las_path=None, meshes_path=None, soundings=None, bounds=None,
                            objects=None, colours=None) -> dict:
    """Write a survey's merged detections (boxes in the survey's working CRS ``crs``, m, rad) as the JSON
    of ``sonardet detect`` (schema_version, scene, method, source, crs, input_crs, detections; `scene` is
    the survey's name: read it with ``read_detections(path, expected_scene=<survey>)``), and optionally as
    CSV (+ sidecar), GeoJSON in WGS 84 (RFC 7946) and in ``crs``, the classified soundings (LAS/LAZ; needs
    ``soundings``, a function returning their chunks, and ``bounds``) and the posed meshes (PLY; needs
    ``objects``): `sonardet.survey.outputs.write_survey_outputs`. Atomic writes; returns the JSON document."""
    paths = OutputPaths.of(json=json_path, csv=csv_path, geojson=geojson_path, geojson_crs=geojson_crs_path,
                           las=las_path, meshes=meshes_path)
    meta = SurveyMeta(survey, method, str(source), crs, input_crs if input_crs is not None else crs, classes)
    return write_survey_outputs(dets, paths, meta, soundings=soundings, bounds=bounds, objects=objects,
                                colours=colours)
