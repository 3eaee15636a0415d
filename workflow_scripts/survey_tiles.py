"""Cut one survey file into tiles (checkpoint survey_tiles): tiles/{tile}.npz and the tile index JSON."""

from common import job

from pathlib import Path

from sonardet.objects import read_object
from sonardet.survey import object_footprint_m, split_survey

with job(snakemake, "survey_tiles") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    survey, cfg = smk.wildcards.survey, smk.params.split
    objects = {Path(p).stem: read_object(p) for p in smk.input.meta}
    footprint = object_footprint_m(objects)
    log.info("%s: largest object footprint %.2f m (classes %s), overlap %g m", survey, footprint,
             ", ".join(objects), cfg["overlap_m"])
    try:
        doc = split_survey(smk.input.survey, smk.output.tiles, smk.output.index, survey=survey,
                           tile_m=cfg["tile_m"], overlap_m=cfg["overlap_m"], crs=cfg["crs"],
                           min_overlap_m=footprint, chunk_points=cfg["chunk_points"], z_positive=cfg["z_positive"],
                           columns=cfg["columns"], keep_fliers=cfg["keep_fliers"])
    except ValueError as exc:
        raise ValueError(f"surveys.{survey}: {exc}") from exc
    log.info("%s: %d points, %d tiles (%d x %d, %d with points), origin %s, CRS %s (input %s)", survey,
             doc["n_points"], len(doc["tiles"]), doc["nx"], doc["ny"], sum(t["file"] is not None for t in doc["tiles"]),
             doc["origin"], doc["crs"], doc["input_crs"])
