"""Surveys: detection on survey files far larger than a tile.

* `extent`: where the soundings are (occupied cells of a coarse grid) and the fliers (a few soundings far
  from the rest), never in proportion to the bounding box;
* `tiling`: plan tiles over a survey's x/y bounds near its data, the ownership rule, the merge of tile detections and
  the one-process tiled detection (`detect_tiled`, used by ``sonardet detect``);
* `split`: the workflow's checkpoint, a survey file cut into tile files by a streaming two-pass split,
  and the tile index;
* `merge`: the tiles' detections merged and written in the survey's own coordinates;
* `settings`: the config's `surveys` entries and the object footprint the tiles' overlap must cover.

Frames and units: metres, in the survey file's own coordinates (its CRS), float64 throughout.
"""

from sonardet.survey.merge import merge_survey_detections, write_survey_detections
from sonardet.survey.settings import (
    SURVEY_DEFAULTS,
    enabled_surveys,
    object_footprint_m,
    survey_defaults,
    survey_settings,
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
from sonardet.survey.extent import FLIER_GAP_M, FLIER_MAX_POINTS, CellStats, Fliers, find_fliers
from sonardet.survey.tiling import (
    SurveyLayout,
    Tile,
    detect_survey,
    detect_tiled,
    merge_tile_detections,
    plan_tiles,
    survey_layout,
    tile_points,
)

__all__ = [
    "DEFAULT_CHUNK_POINTS",
    "FLIER_GAP_M",
    "FLIER_MAX_POINTS",
    "CellStats",
    "Fliers",
    "SurveyLayout",
    "detect_survey",
    "find_fliers",
    "survey_layout",
    "SURVEY_DEFAULTS",
    "SurveyReader",
    "Tile",
    "detect_tiled",
    "enabled_surveys",
    "merge_survey_detections",
    "merge_tile_detections",
    "object_footprint_m",
    "open_survey",
    "plan_tiles",
    "read_tile_index",
    "read_tile_points",
    "split_survey",
    "survey_defaults",
    "survey_settings",
    "tile_ids",
    "tile_points",
    "write_survey_detections",
]
