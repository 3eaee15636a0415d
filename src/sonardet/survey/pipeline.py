"""Detection on one survey file in one process, as ``sonardet detect`` runs it: read (`source`), tile and
detect (`tiling.detect_survey`: fliers left out, tiles near the data), write every requested output (`outputs`).

The steps are separate functions so the command line stays thin and checks can be added between them:
`detect_survey_file` validates the outputs before reading (`OutputPaths.check`), and hands the read
points through ``prepare`` (a function PointCloud -> PointCloud, e.g. dropping fliers) before
detection. The workflow's tiled jobs read through the same `SurveySource` and write through the same
`write_survey_outputs`, so both give the same files.

Frames and units: metres in the working CRS (the input's, or the UTM zone of geographic input), z up.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from sonardet.io.points import PointCloud, iter_slices
from sonardet.survey.outputs import OutputPaths, SurveyMeta, write_survey_outputs
from sonardet.survey.source import SurveyCloud, SurveySource, read_survey
from sonardet.survey.tiling import DEFAULT_TILE_M, check_jobs, detect_survey, plan_tiles

__all__ = ["DetectRun", "SurveyDetection", "detect_survey_file"]


@dataclass(frozen=True)
class DetectRun:
    """How to detect on a survey: the method's name and its loaded detector (points (N, 3) float64 m ->
    detections or (detections, stats)), the classes, tiling (`tile_m`, `overlap_m`, `min_overlap_m`: the
    largest object footprint, all m), whether rejected hypotheses are kept, whether fliers (isolated
    far soundings, `survey.extent`) are kept instead of left out and reported, the object models and class
    colours (for the meshes output), progress bars on a terminal, and `jobs`: tiles detected at once in
    worker processes (`tiling.detect_tiled`; 1: one after another in this process)."""

    method: str
    detector: Callable
    classes: list[str]
    tile_m: float = DEFAULT_TILE_M
    overlap_m: float = 3.0
    min_overlap_m: float | None = None
    all_hypotheses: bool = False
    keep_fliers: bool = False
    objects: Mapping | None = None
    colours: Mapping[str, str] = field(default_factory=dict)
    progress: bool = False
    jobs: int = 1


@dataclass
class SurveyDetection:
    """What `detect_survey_file` did: the survey as read, the JSON document written, the number of
    tiles run, of hypotheses before the accepted-only filter, the detection time (s), the number of soundings
    detection saw (fliers left out) and of worker processes it used (1: none)."""

    survey: SurveyCloud
    doc: dict
    n_tiles: int
    n_hypotheses: int
    detect_seconds: float
    n_detected_points: int = 0
    jobs: int = 1

    @property
    def soundings_per_second(self) -> float:
        """Soundings detection saw per second of detection (0 when no time was measured)."""
        return self.n_detected_points / self.detect_seconds if self.detect_seconds > 0 else 0.0


def detect_survey_file(source: SurveySource, run: DetectRun, paths: OutputPaths, *, name: str | None = None,
                       prepare: Callable[[PointCloud], PointCloud] | None = None,
                       chunk_points: int = 1_000_000) -> SurveyDetection:
    """Detect objects in one survey file and write the outputs ``paths``, in one process.

    Reads the file (`read_survey`: grid check, vertical direction, columns, lon/lat projected to UTM),
    checks the outputs (`OutputPaths.check`) and the tiling before the slow part, hands the cloud to
    ``prepare`` when given, detects (`DetectRun`), keeps the accepted detections unless
    ``run.all_hypotheses`` and writes every output (`write_survey_outputs`; the classified LAS holds the
    soundings detection saw). name: the JSON's scene id (default: the JSON file's stem). Raises
    ValueError / FileNotFoundError naming the file and the option to fix.
    """
    plan_tiles((0.0, 0.0, 0.0, 0.0), run.tile_m, run.overlap_m, run.min_overlap_m)  # bad tiling fails first
    check_jobs(run.jobs)
    survey = read_survey(source)
    cloud = survey.cloud
    paths.check(cloud.crs, bool(run.objects))
    if prepare is not None:
        cloud = prepare(cloud)
    if not len(cloud):
        raise ValueError(f"{source.path}: no points")
    t = time.perf_counter()
    # Fliers dropped unless run.keep_fliers; tiles only near the data (survey.extent).
    dets, info = detect_survey(cloud.xyz, run.detector, run.tile_m, run.overlap_m, run.min_overlap_m,
                               run.keep_fliers, str(source.path), bar=run.progress, jobs=run.jobs)
    n_tiles = info["n_tiles"]
    seconds = time.perf_counter() - t
    n_all = len(dets)
    if not run.all_hypotheses:  # boxes the method accepted as objects (rejected ones only on request)
        dets = [d for d in dets if (d.get("extras") or {}).get("accepted", True)]
    meta = SurveyMeta(name or paths.json.stem, run.method, str(source.path), cloud.crs, survey.input_crs,
                      run.classes)
    bounds = (cloud.xyz.min(axis=0), cloud.xyz.max(axis=0))
    doc = write_survey_outputs(dets, paths, meta, bounds=bounds, objects=run.objects, colours=run.colours,
                               soundings=lambda: (c.xyz for c in iter_slices(cloud, chunk_points)))
    return SurveyDetection(SurveyCloud(cloud, survey.input_crs, survey.projection), doc, n_tiles, n_all, seconds,
                           info["n_points"], info["jobs"])
