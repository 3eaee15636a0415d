"""Surveys: detection on survey files far larger than a tile.

* `extent`: where the soundings are (occupied cells of a coarse grid) and the fliers (a few soundings far
  from the rest), never in proportion to the bounding box;
* `tiling`: plan tiles over a survey's x/y bounds near its data, the ownership rule, the merge of tile detections and
  the tiled detection of a survey held in memory (`detect_tiled`, used by ``sonardet detect``; tiles
  in parallel worker processes with ``jobs``);
* `split`: the workflow's checkpoint, a survey file cut into tile files by a streaming two-pass split,
  and the tile index;
* `merge`: the tiles' detections merged and written in the survey's own coordinates;
* `settings`: the config's `surveys` entries and the object footprint the tiles' overlap must cover;
* `source`: reading a survey file as surveyors export it (soundings or GeoTIFF/BAG grids, elevation or
  depth, projected or lon/lat projected to UTM), whole or chunk by chunk;
* `outputs`: the files people open: detection JSON, CSV + sidecar, GeoJSON (WGS 84 and the survey CRS),
  classified LAS/LAZ soundings, posed meshes (PLY);
* `pipeline`: read, tile, detect and write for one file in one process (``sonardet detect``).

Frames and units: metres, in the survey file's own coordinates (its CRS), float64 throughout.
"""

from sonardet.survey.extent import (
    FLIER_GAP_M,
    FLIER_MAX_POINTS,
    CellStats,
    Fliers,
    find_fliers,
)
from sonardet.survey.merge import merge_survey_detections, write_survey_detections
from sonardet.survey.outputs import (
    CLASS_OBJECT,
    CLASS_SEABED,
    OutputPaths,
    SurveyMeta,
    classify_soundings,
    write_classified_las,
    write_posed_meshes,
    write_survey_outputs,
)
from sonardet.survey.pipeline import DetectRun, SurveyDetection, detect_survey_file
from sonardet.survey.settings import (
    SURVEY_DEFAULTS,
    enabled_surveys,
    object_footprint_m,
    survey_defaults,
    survey_settings,
)
from sonardet.survey.source import (
    MAX_GRID_CELL_M,
    SurveyCloud,
    SurveySource,
    read_survey,
    survey_chunks,
)
from sonardet.survey.split import (
    DEFAULT_CHUNK_POINTS,
    SurveyReader,
    open_survey,
    read_tile_index,
    read_tile_points,
    split_survey,
    tile_ids,
)
from sonardet.survey.tiling import (
    DEFAULT_TILE_M,
    SurveyLayout,
    Tile,
    available_cores,
    check_jobs,
    detect_survey,
    detect_tiled,
    merge_tile_detections,
    plan_tiles,
    survey_layout,
    tile_points,
)

__all__ = [
    "CLASS_OBJECT",
    "CLASS_SEABED",
    "DEFAULT_CHUNK_POINTS",
    "DEFAULT_TILE_M",
    "FLIER_GAP_M",
    "FLIER_MAX_POINTS",
    "CellStats",
    "Fliers",
    "SurveyLayout",
    "detect_survey",
    "find_fliers",
    "survey_layout",
    "MAX_GRID_CELL_M",
    "SURVEY_DEFAULTS",
    "DetectRun",
    "OutputPaths",
    "SurveyCloud",
    "SurveyDetection",
    "SurveyMeta",
    "SurveyReader",
    "SurveySource",
    "Tile",
    "available_cores",
    "check_jobs",
    "classify_soundings",
    "detect_survey_file",
    "detect_tiled",
    "enabled_surveys",
    "merge_survey_detections",
    "merge_tile_detections",
    "object_footprint_m",
    "open_survey",
    "plan_tiles",
    "read_survey",
    "read_tile_index",
    "read_tile_points",
    "split_survey",
    "survey_chunks",
    "survey_defaults",
    "survey_settings",
    "tile_ids",
    "tile_points",
    "write_classified_las",
    "write_posed_meshes",
    "write_survey_detections",
    "write_survey_outputs",
]
