"""Merge the tile detections of one survey (each object once) and write them in the survey's
coordinates (JSON, CSV + sidecar, GeoJSON in WGS 84 and in the survey CRS, the classified soundings as
LAZ, the posed meshes as PLY), with a per-tile summary (all or none)."""

from common import job

import json
from pathlib import Path

from sonardet.io.annotations import read_detections
from sonardet.io.artifacts import read_json_file
from sonardet.io.atomic import atomic_outputs, atomic_write_text
from sonardet.objects import classes as class_specs
from sonardet.objects import read_object
from sonardet.survey import (
    SurveySource,
    merge_survey_detections,
    read_tile_index,
    survey_chunks,
    write_survey_detections,
)

with job(snakemake, "survey_detections") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    survey = smk.wildcards.survey
    index, tiles = read_tile_index(smk.input.index)
    per_tile = {Path(p).stem: read_detections(p, smk.params.classes)["detections"] for p in smk.input.detections}
    stats = {Path(p).stem: read_json_file(p, "tile statistics file") for p in smk.input.stats}
    dets, rows = merge_survey_detections(index, tiles, per_tile)
    if not smk.params.all_hypotheses:  # accepted objects only, as `sonardet detect` writes by default
        dets = [d for d in dets if (d.get("extras") or {}).get("accepted", True)]
    rd = smk.params.read
    source = SurveySource.of(smk.input.survey, crs=rd["crs"], z_positive=rd["z_positive"], columns=rd["columns"])
    bounds = ([index["bounds"][0], index["bounds"][1], index["z_range"][0]],
              [index["bounds"][2], index["bounds"][3], index["z_range"][1]])
    objects = {Path(p).stem: read_object(p) for p in smk.input.meta}
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
    names = ["json", "csv", "csv_meta", "geojson", "geojson_crs", "las", "objects", "summary"]
    with atomic_outputs([getattr(out, n) for n in names]) as staged:  # every output or none
        s = dict(zip(names, staged))  # the CSV writer puts its sidecar (csv_meta) beside the staged CSV
        write_survey_detections(
            dets, s["json"], s["csv"], s["geojson"], survey=survey, method=smk.params.method,
            source=smk.params.source, crs=index["crs"], classes=smk.params.classes, input_crs=index.get("input_crs"),
            geojson_crs_path=s["geojson_crs"], las_path=s["las"], meshes_path=s["objects"],
            soundings=lambda: (c.xyz for c in survey_chunks(source, rd["chunk_points"])[1]), bounds=bounds,
            objects=objects, colours={c: class_specs.get(c).colour for c in objects})
        atomic_write_text(s["summary"], json.dumps(summary, indent=1) + "\n")
    log.info("%s: %d tiles (%d with points), %d detections after the merge (%d accepted), %.1f s of detection; "
             "coordinates in %s", survey, len(rows), len(per_tile), len(dets), n_acc, summary["detector_seconds"],
             index["crs"] or "the survey file's frame")
