"""Reading a survey file the way surveyors export it: soundings or gridded bathymetry, elevation or depth,
projected or longitude/latitude, into float64 metres in a projected CRS, z up.

`SurveySource` says how to read a file: its path, the CRS when the file carries none (``--crs``), the
vertical direction (``--z-positive up|down``) and the column names of a text file (``--columns``). Both
``sonardet detect`` (`read_survey`, the whole file) and the workflow's tiling (`survey_chunks`, chunk by
chunk) read through it, so they see the same coordinates:

* gridded files (GeoTIFF, BAG) are refused when their cells are coarser than `MAX_GRID_CELL_M`
  (0.25 m): the default reef elements are 1.4-2.7 m across, so a coarser grid holds a handful of nodes
  per object and its shape is gone;
* geographic coordinates (longitude/latitude columns, EPSG:4326 or any geographic ``--crs``, a
  geographic raster) are projected with pyproj to the UTM zone of the file's first sounding, on the
  same datum (`sonardet.io.crs.utm_projection`); detection then runs in that UTM CRS, and the outputs
  are in it (with WGS 84 lon/lat columns and GeoJSON). Projected CRSs (and compound and vertical
  ones) pass through unchanged: the outputs are in the input's CRS.

Frames and units: metres (the projected CRS), z up (elevation), float64 throughout.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from itertools import chain
from pathlib import Path

from sonardet.io.crs import (
    Projection,
    check_lonlat_range,
    is_geographic,
    parse_crs,
    utm_projection,
)
from sonardet.io.points import (
    DEFAULT_CHUNK_POINTS,
    PointCloud,
    PointCloudError,
    grid_cell_m,
    iter_chunks,
    read_points,
)

__all__ = ["MAX_GRID_CELL_M", "SurveySource", "read_survey", "survey_chunks"]

#: Coarsest grid cell (m) of gridded bathymetry that still resolves the reef elements (1.4-2.7 m
#: across: at 0.25 m an element spans 6-11 nodes).
MAX_GRID_CELL_M = 0.25


@dataclass(frozen=True)
class SurveySource:
    """How to read one survey file.

    path: the file (any suffix of ``sonardet.io.points``). crs: the CRS of its coordinates when the file
    carries none (``--crs``, ``surveys.<name>.crs``). z_positive: ``"up"``, ``"down"`` or None (from the
    file: see ``sonardet.io.points``). columns: the column names of a text file in order, or None.
    max_cell_m: the coarsest grid cell accepted (m).
    """

    path: Path
    crs: str | None = None
    z_positive: str | None = None
    columns: tuple[str, ...] | None = None
    max_cell_m: float = MAX_GRID_CELL_M

    @classmethod
    def of(cls, path, crs: str | None = None, z_positive: str | None = None,
           columns: Sequence[str] | str | None = None) -> SurveySource:
        """A source from loose settings; ``columns`` may be a list or one comma-separated string."""
        if isinstance(columns, str):
            columns = [c.strip() for c in columns.split(",")]
        return cls(Path(path), crs, z_positive, tuple(columns) if columns else None)

    def read_options(self) -> dict:
        """The keywords of ``read_points``/``iter_chunks`` (only those that are set)."""
        given = {"crs": self.crs, "columns": list(self.columns) if self.columns else None, "z_positive": self.z_positive}
        return {k: v for k, v in given.items() if v is not None}

    def check_grid(self) -> float | None:
        """The node spacing (m) of a gridded file, None for soundings; a grid coarser than `max_cell_m`
        raises PointCloudError naming the file and the limit. A ``crs`` pyproj cannot parse raises first
        (CrsError naming ``--crs``)."""
        if self.crs is not None:
            parse_crs(self.crs, str(self.path), "--crs")
        cell = grid_cell_m(self.path, self.crs)
        if cell is not None and cell > self.max_cell_m + 1e-9:
            raise PointCloudError(
                f"{self.path}: the grid's cells are {cell:.3g} m, coarser than {self.max_cell_m:g} m: the reef "
                f"elements (1.4-2.7 m across) are then a few nodes each and cannot be resolved; export the "
                f"bathymetry at {self.max_cell_m:g} m or finer, or give the soundings (XYZ, LAS/LAZ) instead")
        return cell


@dataclass
class SurveyCloud:
    """A survey read for detection: ``cloud`` (float64 metres in ``cloud.crs``, a projected CRS or
    unknown; z up), the CRS of the file's own coordinates ``input_crs``, and the ``projection`` applied
    (None when the coordinates were already metric)."""

    cloud: PointCloud
    input_crs: str | None
    projection: Projection | None


def _project(cloud: PointCloud, projection: Projection) -> PointCloud:
    """``cloud`` (longitude, latitude, z) in the projection's UTM CRS (metres), attributes kept."""
    check_lonlat_range(cloud.xyz, projection.source_crs, str(cloud.source))
    return PointCloud(projection.forward(cloud.xyz), cloud.attributes, crs=projection.target_crs,
                      source=cloud.source)


def _projection_of(cloud: PointCloud) -> Projection | None:
    """The UTM projection of a geographic cloud (zone of its first point), None for a metric one."""
    if not is_geographic(cloud.crs):
        return None
    return utm_projection(cloud.crs, cloud.xyz[:1], str(cloud.source))


def read_survey(source: SurveySource) -> SurveyCloud:
    """Read a whole survey file (see the module doc): checks the grid cell of gridded files, reads with
    the source's options, projects geographic coordinates to UTM (metres). Raises FileNotFoundError,
    PointCloudError / CrsError (ValueError) naming the file and the option to fix."""
    source.check_grid()
    cloud = read_points(source.path, **source.read_options())
    projection = _projection_of(cloud)
    if projection is not None:
        cloud = _project(cloud, projection)
    return SurveyCloud(cloud, projection.source_crs if projection else cloud.crs, projection)


def survey_chunks(source: SurveySource, chunk_points: int = DEFAULT_CHUNK_POINTS
                  ) -> tuple[SurveyCloud, Iterator[PointCloud]]:
    """Read a survey file chunk by chunk (``sonardet.io.points.iter_chunks``; see the module doc): returns
    (the first chunk as a `SurveyCloud`, saying the working CRS, the input CRS and the projection; an
    iterator over every chunk, the first included, in file order) with x, y, z only, metres in the
    working CRS. The first chunk is read here, so an unreadable file fails here."""
    source.check_grid()
    chunks = iter_chunks(source.path, chunk_points=chunk_points, **source.read_options())
    first = next(chunks, None)
    if first is None:  # every reader yields a chunk or raises ("no points"); a safety net
        raise PointCloudError(f"{source.path}: no points")
    projection = _projection_of(first)
    if projection is None:
        return SurveyCloud(first, first.crs, None), chain([first], chunks)
    head = _project(first, projection)
    return (SurveyCloud(head, projection.source_crs, projection),
            chain([head], (_project(c, projection) for c in chunks)))
