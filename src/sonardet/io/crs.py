"""Coordinate reference systems through pyproj: parsing and naming CRSs, choosing the UTM zone of
geographic (longitude/latitude) data and projecting them there, and WGS 84 longitude/latitude of
projected coordinates for GIS outputs.

Conventions:

* A CRS travels through the project as a string (``PointCloud.crs``, the detection JSON's ``crs``):
  ``"AUTH:CODE"`` when pyproj finds an authority code (``"EPSG:32610"``), ``"AUTH:H+V"`` for a compound
  CRS whose parts have codes but the whole has none (``"EPSG:32610+5703"``, which pyproj reads back),
  else the CRS's WKT2. :func:`crs_string` makes it; :func:`parse_crs` reads any spelling pyproj takes.
* Axis order is always x = easting or longitude, y = northing or latitude (pyproj ``always_xy``),
  whatever order the authority defines (EPSG:4326 is latitude first).
* Vertical and compound CRSs pass through: z is never transformed here. Projecting a compound
  geographic + vertical CRS gives the compound UTM + the same vertical CRS.
* Units: metres for projected CRSs, degrees for geographic ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "LAT_RANGE_UTM_DEG",
    "LONLAT_CRS",
    "CrsError",
    "Projection",
    "check_lonlat_range",
    "crs_string",
    "has_horizontal",
    "horizontal_crs",
    "is_geographic",
    "is_projected",
    "lonlat_of",
    "parse_crs",
    "utm_projection",
]

#: The CRS of RFC 7946 GeoJSON and of the longitude/latitude columns of the CSV export.
LONLAT_CRS = "EPSG:4326"
#: Latitudes (degrees) covered by the UTM zones; beyond them lie the polar (UPS) areas.
LAT_RANGE_UTM_DEG = (-80.0, 84.0)


class CrsError(ValueError):
    """A CRS that pyproj does not understand or that does not fit the data; the message names the
    file or option and the fix."""


def parse_crs(crs: str, where: str = "crs", flag: str = "--crs"):
    """The ``pyproj.CRS`` of a CRS string (``"EPSG:32610"``, ``"epsg:4326"``, WKT, PROJ JSON, a URN).

    Raises :class:`CrsError` naming ``where`` and ``flag`` when pyproj cannot parse it.
    """
    import pyproj

    try:
        return pyproj.CRS.from_user_input(crs)
    except pyproj.exceptions.CRSError as exc:
        raise CrsError(f"{where}: pyproj does not understand the CRS {crs!r} ({exc}); give it as EPSG:<code> "
                       f"or WKT with {flag}") from None


def crs_string(crs) -> str:
    """The project's spelling of a CRS (a ``pyproj.CRS`` or any string pyproj parses): ``"AUTH:CODE"``,
    ``"AUTH:H+V"`` for a compound CRS whose parts have codes, else WKT2 (see the module doc)."""
    obj = parse_crs(crs) if isinstance(crs, str) else crs
    own = obj.to_json_dict().get("id")  # the CRS's own identifier (WKT1 AUTHORITY / WKT2 ID of its root)
    if own and "authority" in own and "code" in own:
        return f"{own['authority']}:{own['code']}"
    auth = obj.to_authority(min_confidence=70)
    if auth:
        return f"{auth[0]}:{auth[1]}"
    if obj.is_compound:
        parts = [p.to_authority(min_confidence=70) for p in obj.sub_crs_list]
        if all(parts) and len({p[0] for p in parts}) == 1:
            return f"{parts[0][0]}:" + "+".join(p[1] for p in parts)
    return obj.to_wkt()


def horizontal_crs(crs):
    """The horizontal part of a ``pyproj.CRS`` (the first component of a compound CRS, else itself)."""
    return crs.sub_crs_list[0] if crs.is_compound else crs


def is_geographic(crs: str | None) -> bool:
    """Whether the CRS string's horizontal part is geographic (longitude/latitude in degrees); None:
    False."""
    return crs is not None and bool(horizontal_crs(parse_crs(crs)).is_geographic)


def is_projected(crs: str | None) -> bool:
    """Whether the CRS string's horizontal part is projected (metres or feet on a map plane); None:
    False."""
    return crs is not None and bool(horizontal_crs(parse_crs(crs)).is_projected)


def has_horizontal(crs: str | None) -> bool:
    """Whether positions in the CRS string can be placed on the globe: its horizontal part is projected or
    geographic (False for None and for a vertical-only CRS)."""
    if crs is None:
        return False
    h = horizontal_crs(parse_crs(crs))
    return bool(h.is_projected or h.is_geographic)


def _utm_of(geo, lon: float, lat: float):
    """The UTM CRS (pyproj) on the datum of the geographic CRS `geo` for a position (degrees): an
    authority's code when one exists (EPSG:326zz/327zz for WGS 84, 269zz for NAD83, ...), else the UTM
    conversion on `geo` itself."""
    import pyproj
    from pyproj.aoi import AreaOfInterest
    from pyproj.crs.coordinate_operation import UTMConversion
    from pyproj.database import query_utm_crs_info

    aoi = AreaOfInterest(lon, lat, lon, lat)
    names = [n for n in (geo.datum.name if geo.datum else None, geo.name) if n]
    if any("WGS 84" in n or "World Geodetic System 1984" in n for n in names):
        names = ["WGS 84"]
    for name in names:
        found = query_utm_crs_info(datum_name=name, area_of_interest=aoi)
        if found:
            return pyproj.CRS.from_authority(found[0].auth_name, found[0].code)
    zone = int(math.floor((lon + 180.0) / 6.0)) % 60 + 1
    conversion = UTMConversion(zone, "south" if lat < 0 else "north")
    return pyproj.crs.ProjectedCRS(conversion=conversion, geodetic_crs=geo, name=f"{geo.name} / UTM zone {zone}")


@dataclass
class Projection:
    """Geographic coordinates (longitude, latitude in degrees, z as given) to the UTM zone of the data
    (metres; z unchanged). ``source_crs`` and ``target_crs`` are CRS strings (:func:`crs_string`);
    ``target_crs`` keeps the vertical part of a compound source."""

    source_crs: str
    target_crs: str
    _forward: Any = field(default=None, repr=False, compare=False)

    def forward(self, xyz: np.ndarray) -> np.ndarray:
        """(N, 3) lon (deg), lat (deg), z (m) -> float64 (N, 3) easting, northing (m), z (m) unchanged."""
        import pyproj

        if self._forward is None:
            self._forward = pyproj.Transformer.from_crs(
                horizontal_crs(parse_crs(self.source_crs)), horizontal_crs(parse_crs(self.target_crs)),
                always_xy=True)
        out = np.array(xyz, dtype=np.float64, copy=True)
        out[:, 0], out[:, 1] = self._forward.transform(out[:, 0], out[:, 1])
        return out


def check_lonlat_range(xyz: np.ndarray, crs: str, where: str, flag: str = "--crs") -> None:
    """Raise :class:`CrsError` when any point of geographic coordinates (x = longitude, y = latitude,
    degrees) lies outside the UTM zones' range (longitude -180..180, latitude -80..84): the CRS does not
    fit the data (e.g. projected coordinates declared EPSG:4326) or the data reach the polar areas. The
    message names ``where``, the first such point and ``flag``."""
    lon, lat = xyz[:, 0], xyz[:, 1]
    lo, hi = LAT_RANGE_UTM_DEG
    bad = (np.abs(lon) > 180.0) | (lat < lo) | (lat > hi)
    if bad.any():
        i = int(np.argmax(bad))
        raise CrsError(
            f"{where}: {int(bad.sum())} of {len(xyz)} soundings are not longitude/latitude in a UTM zone's range "
            f"(longitude -180..180, latitude {lo:g}..{hi:g} degrees), e.g. point {i} at x = {lon[i]!r}, y = "
            f"{lat[i]!r}, but the CRS {crs} is geographic: give the CRS of the coordinates with {flag} (e.g. "
            "EPSG:32610 for UTM zone 10N metres), or name the columns with --columns if x and y are swapped")


def utm_projection(crs: str, xyz: np.ndarray, where: str, flag: str = "--crs") -> Projection:
    """The :class:`Projection` of geographic data (x = longitude, y = latitude in degrees, CRS string
    ``crs``) to the UTM zone of their first point (so every chunk of a file gets the same zone), on the
    CRS's datum; a vertical part of a compound ``crs`` is kept. The points are checked first
    (:func:`check_lonlat_range`). Raises :class:`CrsError` for a CRS that is not geographic."""
    import pyproj

    src = parse_crs(crs, where, flag)
    geo = horizontal_crs(src)
    if not geo.is_geographic:
        raise CrsError(f"{where}: the CRS {crs} is not geographic; nothing to project")
    check_lonlat_range(xyz, crs, where, flag)
    utm = _utm_of(geo, float(xyz[0, 0]), float(xyz[0, 1]))
    if src.is_compound:
        utm = pyproj.crs.CompoundCRS(name=f"{utm.name} + {src.sub_crs_list[1].name}",
                                     components=[utm, src.sub_crs_list[1]])
    return Projection(crs_string(src), crs_string(utm))


def lonlat_of(x, y, crs: str) -> tuple[np.ndarray, np.ndarray]:
    """WGS 84 longitude and latitude (degrees, float64) of positions x, y (arrays or scalars) in the
    CRS ``crs`` (its horizontal part; pyproj, always_xy)."""
    import pyproj

    t = pyproj.Transformer.from_crs(horizontal_crs(parse_crs(crs)), LONLAT_CRS, always_xy=True)
    lon, lat = t.transform(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    return np.asarray(lon, dtype=np.float64), np.asarray(lat, dtype=np.float64)
