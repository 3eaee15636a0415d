"""Merge the tile detections of one survey (each object once) and write them in the survey's
coordinates as JSON, CSV and GeoJSON, with a per-tile summary (all four or none)."""

from common import job

import json
from pathlib import Path

from sonardet.io.annotations import read_detections
from sonardet.io.artifacts import read_json_file
from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.survey import merge_survey_detections, read_tile_index, write_survey_detections

with job(snakemake, "survey_detections") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    survey = smk.wildcards.survey
    index, tiles = read_tile_index(smk.input.index)
    per_tile = {Path(p).stem: read_detections(p, smk.params.classes)["detections"] for p in smk.input.detections}
    stats = {Path(p).stem: read_json_file(p, "tile statistics file") for p in smk.input.stats}
    dets, rows = merge_survey_detections(index, tiles, per_tile)
    if not smk.params.all_hypotheses:  # accepted objects only, as `sonardet detect` writes by default
        dets = [d for d in dets if (d.get("extras") or {}).get("accepted", True)]
    for row in rows:
        row["seconds"] = stats[row["tile"]]["seconds"]["total"] if row["tile"] in stats else 0.0
        log.info("%s %s: %d points, %d detections, %d owned by the tile, %.1f s", survey, row["tile"],
                 row["n_points"], row["n_detections"], row["n_kept"], row["seconds"])
    n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
    summary = {"survey": survey, "source": smk.params.source, "crs": index["crs"], "method": smk.params.method,
               "origin": index["origin"], "n_points": index["n_points"], "bounds": index["bounds"],
               "tile_m": index["tile_m"], "overlap_m": index["overlap_m"], "n_tiles": len(rows),
               "n_tiles_with_points": len(per_tile), "n_detections": len(dets), "n_accepted": n_acc,
               "detector_seconds": sum(r["seconds"] for r in rows), "fliers": index.get("fliers"), "tiles": rows}
    out = smk.output
    with atomic_outputs([out.json, out.csv, out.geojson, out.summary]) as (js, csv, geojson, summary_path):
        write_survey_detections(dets, js, csv, geojson, survey=survey, method=smk.params.method,
                                source=smk.params.source, crs=index["crs"], classes=smk.params.classes)
        atomic_write_text(summary_path, json.dumps(summary, indent=1) + "\n")
    log.info("%s: %d tiles (%d with points), %d detections after the merge (%d accepted), %.1f s of detection; "
             "coordinates in %s", survey, len(rows), len(per_tile), len(dets), n_acc, summary["detector_seconds"],
             index["crs"] or "the survey file's frame")
