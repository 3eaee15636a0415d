"""Settings of the config's `surveys` entries and the object footprint the tiles' overlap must cover."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sonardet.io.points import DEFAULT_CHUNK_POINTS
from sonardet.survey.tiling import DEFAULT_TILE_M

__all__ = ["SURVEY_DEFAULTS", "enabled_surveys", "object_footprint_m", "survey_defaults", "survey_settings"]

#: Default settings of one entry of the config's `surveys` block: enabled, crs, z_positive (up, down or
#: null: from the file), columns (text files' column names, or null), method, tile_m (m), overlap_m (m),
#: chunk_points, all_hypotheses, keep_fliers. `path` has no default. The config schema
#: (`surveys.additionalProperties.properties.*.default` in sonardet/data/schema.yaml) states the same
#: defaults; tests/test_survey_workflow.py checks that the two agree.
SURVEY_DEFAULTS: dict = {
    "enabled": True,
    "crs": None,
    "z_positive": None,
    "columns": None,
    "method": "model_based_ours",
    "tile_m": DEFAULT_TILE_M,
    "overlap_m": 3.0,
    "chunk_points": DEFAULT_CHUNK_POINTS,
    "all_hypotheses": False,
    "keep_fliers": False,
}


def survey_defaults() -> dict:
    """Default settings of one entry of the config's `surveys` block (a copy of `SURVEY_DEFAULTS`):
    enabled, crs, z_positive, columns, method, tile_m (m), overlap_m (m), chunk_points, all_hypotheses.
    `path` has no default."""
    return dict(SURVEY_DEFAULTS)


def survey_settings(name: str, entry: Mapping) -> dict:
    """One survey's settings: `entry` (a validated `surveys.<name>` config block) completed with the
    defaults (`SURVEY_DEFAULTS`), plus its `name`. Raises ValueError when `path` is missing."""
    if "path" not in entry:
        raise ValueError(f"surveys.{name}: needs `path`, the survey's point-cloud file")
    return {**survey_defaults(), **dict(entry), "name": name}


def enabled_surveys(surveys: Mapping) -> tuple[dict, list[str]]:
    """The surveys the workflow runs: (name -> settings of `survey_settings`, messages).

    Surveys with `enabled: false` are left out silently; a survey whose file does not exist is left
    out with a message (for the workflow to print at start-up) saying how to fix or silence it.
    Relative paths are relative to the working directory.
    """
    out, messages = {}, []
    for name, entry in (surveys or {}).items():
        s = survey_settings(name, entry)
        if not s["enabled"]:
            continue
        if not Path(s["path"]).is_file():
            messages.append(
                f"sonardet: surveys.{name}.path {s['path']} not found: the survey {name!r} is left out of this "
                f"run (set surveys.{name}.path to the survey file, or surveys.{name}.enabled: false to "
                "silence this)")
            continue
        out[name] = s
    return out, messages


def object_footprint_m(objects: Mapping) -> float:
    """Largest horizontal footprint (m) of the classes' meshes at any yaw: twice the largest distance
    of a vertex from the class's vertical axis (the canonical frame's z axis), as ``sonardet detect``
    computes it. The tiles' overlap must be at least this for the ownership rule to be exact.
    `objects`: class -> ObjectInfo (anything with `.mesh.vertices`)."""
    if not objects:
        raise ValueError("object_footprint_m: no object models given")
    return max(2.0 * float(np.max(np.hypot(*np.asarray(o.mesh.vertices)[:, :2].T))) for o in objects.values())
