"""Sonar noise characterisation on a flat reference patch (the source study's appendix).

Method: select the points of a flat patch of the seabed; find the plane with RANSAC (Open3D
``segment_plane``), refine it by least squares (SVD) on the RANSAC inliers; take the signed
point-to-plane distances of all patch points; compute their z-scores and trim the points with
``|z| > z_trim`` (2 by default); report mean, standard deviation, robust sigma and D'Agostino's
skewness test (``scipy.stats.skewtest``) before and after trimming.

Frames and units: metres. Input points are float64 in the caller's frame (scene frame, or a
projected CRS such as UTM with eastings ~5e5 m and northings ~4e6 m). Georeferenced input
(|x| or |y| > ``LOCAL_LIMIT_M``) is shifted by a local origin (:func:`sonardet.io.origin.choose_origin`)
in float64 before any Open3D work; the plane is reported in that local frame together with the
origin. Distances are positive above the plane (the plane normal points up, +z).

:func:`simulated_flat_patch` scans a flat seabed with the project's own sensor model, so the
simulator's noise can be characterised the same way as a real survey's.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
import trimesh
from matplotlib.path import Path as MplPath
from scipy import stats

from sonardet.io.origin import LOCAL_LIMIT_M, choose_origin, finite_xyz
from sonardet.ransac import segment_plane

__all__ = [
    "ARRAY_KEYS",
    "MIN_POINTS",
    "MAD_TO_SIGMA",
    "characterize_noise",
    "select_patch",
    "simulated_flat_patch",
    "to_json",
]

#: Fewest patch points :func:`characterize_noise` accepts.
MIN_POINTS = 50
#: Fewest points ``scipy.stats.skewtest`` accepts.
MIN_SKEWTEST_POINTS = 8
#: Scale from the median absolute deviation to the standard deviation of a normal distribution.
MAD_TO_SIGMA = 1.4826
#: Keys of the :func:`characterize_noise` result that hold numpy arrays (dropped by :func:`to_json`).
ARRAY_KEYS = ("distances_m", "kept_mask")
# Re-selection rounds of the inlier set after the first least-squares refinement.
_MAX_REFINE_ROUNDS = 10


def _local_origin(xyz: np.ndarray) -> np.ndarray:
    """choose_origin(xyz) for georeferenced points (|x| or |y| > LOCAL_LIMIT_M), else zeros (float64, m)."""
    if len(xyz) and np.abs(xyz[:, :2]).max() > LOCAL_LIMIT_M:
        return choose_origin(xyz)
    return np.zeros(3, dtype=np.float64)


def _interval(patch: dict, key: str) -> tuple[float, float]:
    vals = patch[key]
    try:
        lo, hi = (float(v) for v in vals)
    except (TypeError, ValueError):
        raise ValueError(f"patch {key!r}: expected [min, max] in metres, got {vals!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"patch {key!r}: expected finite [min, max] with min < max, got {vals!r}")
    return lo, hi


def _polygon(patch: dict) -> np.ndarray:
    try:
        poly = np.asarray(patch["polygon"], dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"patch 'polygon': expected [[x, y], ...] in metres, got {patch['polygon']!r}") from None
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 3:
        raise ValueError(f"patch 'polygon': expected at least 3 vertices [[x, y], ...], got shape {poly.shape}")
    if not np.isfinite(poly).all():
        raise ValueError("patch 'polygon': vertices must be finite")
    return poly


def _patch_kind(patch: dict) -> str:
    """'box' or 'polygon'; raise for anything else."""
    if not isinstance(patch, dict):
        raise ValueError(f"patch: expected a dict ({{'x': [min, max], 'y': [min, max]}} or "
                         f"{{'polygon': [[x, y], ...]}}), got {type(patch).__name__}")
    keys = set(patch) - {"name"}
    if keys == {"x", "y"}:
        return "box"
    if keys == {"polygon"}:
        return "polygon"
    raise ValueError(
        f"patch: keys {sorted(patch)} are neither a box {{'x': [min, max], 'y': [min, max]}} nor a "
        "polygon {'polygon': [[x, y], ...]} (an optional 'name' is allowed)"
    )


def _describe(patch: dict | None, name: str) -> str:
    """Short label of a patch for messages."""
    if name:
        return f"patch {name!r}"
    if patch is None:
        return "patch (all points)"
    if _patch_kind(patch) == "box":
        return f"patch x {list(patch['x'])} y {list(patch['y'])}"
    return f"polygon patch with {len(patch['polygon'])} vertices"


def _patch_json(patch: dict | None) -> dict | None:
    """The patch as plain JSON types."""
    if patch is None:
        return None
    out: dict[str, Any] = {}
    if "name" in patch:
        out["name"] = str(patch["name"])
    if _patch_kind(patch) == "box":
        out["x"] = list(_interval(patch, "x"))
        out["y"] = list(_interval(patch, "y"))
    else:
        out["polygon"] = _polygon(patch).tolist()
    return out


def select_patch(xyz, patch: dict) -> np.ndarray:
    """Boolean mask (N,) of the points of ``xyz`` (N, 3), metres, inside ``patch``.

    ``patch`` is in the same frame/CRS as the points: an axis-aligned box
    ``{"x": [min, max], "y": [min, max]}`` (bounds inclusive) or a polygon
    ``{"polygon": [[x, y], ...]}`` (``matplotlib.path.Path.contains_points``; points exactly on
    the boundary may fall either side). An optional ``"name"`` key is ignored. Only x and y are
    tested. Georeferenced coordinates are shifted to a local origin in float64 before the polygon
    test. Raises ``ValueError`` for a malformed patch or non-finite points (naming the row).
    """
    pts = finite_xyz(xyz)
    if _patch_kind(patch) == "box":
        x0, x1 = _interval(patch, "x")
        y0, y1 = _interval(patch, "y")
        x, y = pts[:, 0], pts[:, 1]
        return (x >= x0) & (x <= x1) & (y >= y0) & (y <= y1)
    poly = _polygon(patch)
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    origin = _local_origin(pts)
    path = MplPath(poly - origin[:2])
    return np.asarray(path.contains_points(pts[:, :2] - origin[:2]), dtype=bool)


def _svd_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares plane of (M, 3) float64 points: (unit normal with n_z >= 0, centroid, singular values)."""
    centroid = points.mean(axis=0)
    _, s, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[-1]
    # Orient the normal up so that positive distances lie above the seabed.
    lead = normal[2] if normal[2] != 0 else normal[np.flatnonzero(normal)[0]]
    if lead < 0:
        normal = -normal
    return normal, centroid, s


def _stats(d: np.ndarray) -> dict[str, Any]:
    """Summary of distances d (metres): n, mean, std (ddof=1), rms, robust sigma, skewness and D'Agostino test."""
    n = int(len(d))
    out: dict[str, Any] = {"n": n, "mean_m": None, "std_m": None, "rms_m": None, "median_m": None,
                           "robust_sigma_m": None, "skewness": None,
                           "skewtest_statistic": None, "skewtest_pvalue": None}
    if n == 0:
        return out
    med = float(np.median(d))
    out["mean_m"] = float(np.mean(d))
    out["median_m"] = med
    out["rms_m"] = float(np.sqrt(np.mean(d * d)))
    out["robust_sigma_m"] = float(MAD_TO_SIGMA * np.median(np.abs(d - med)))
    if n >= 2:
        out["std_m"] = float(np.std(d, ddof=1))
    # Constant data have no defined skewness; scipy's test needs n >= 8.
    if n >= 3 and np.ptp(d) > 0:
        out["skewness"] = float(stats.skew(d))
        if n >= MIN_SKEWTEST_POINTS:
            res = stats.skewtest(d)
            out["skewtest_statistic"] = float(res.statistic)
            out["skewtest_pvalue"] = float(res.pvalue)
    return out


def _check_noise_settings(ransac_distance_m: float, ransac_n: int, iterations: int, z_trim: float) -> None:
    """Raise ValueError for a non-positive distance (m), fewer than 3 points per sample, no iteration
    or a non-positive trimming threshold (standard deviations)."""
    if not (math.isfinite(ransac_distance_m) and ransac_distance_m > 0):
        raise ValueError(f"ransac_distance_m must be a positive number of metres, got {ransac_distance_m!r}")
    if int(ransac_n) < 3:
        raise ValueError(f"ransac_n must be >= 3 (points per plane sample), got {ransac_n!r}")
    if int(iterations) < 1:
        raise ValueError(f"iterations must be >= 1, got {iterations!r}")
    if not (math.isfinite(z_trim) and z_trim > 0):
        raise ValueError(f"z_trim must be a positive number of standard deviations, got {z_trim!r}")


def _patch_points(pts: np.ndarray, patch: dict | None, label: str) -> np.ndarray:
    """The points (M, 3) of `pts` inside `patch` (all without one); at least MIN_POINTS of them."""
    sel = pts if patch is None else pts[select_patch(pts, patch)]
    if len(sel) < MIN_POINTS:
        raise ValueError(f"{label}: {len(sel)} points, need at least {MIN_POINTS} to characterise noise")
    return sel


def _is_degenerate(singular_values: np.ndarray) -> bool:
    """Whether points with these singular values (about their centroid) are collinear or coincident."""
    s = singular_values
    return bool(s[1] <= 1e-9 * max(s[0], np.finfo(float).tiny))


def _ransac_plane(local: np.ndarray, ransac_distance_m: float, ransac_n: int, iterations: int, seed: int,
                  label: str):
    """RANSAC plane of local-frame points (M, 3), m (Open3D ``segment_plane``, seeded, one thread): (plane model
    [a, b, c, d], boolean inlier mask (M,)). Raises when it finds fewer than 3 inliers."""
    model, inliers = segment_plane(local, ransac_distance_m, ransac_n, iterations, seed)
    inl = np.zeros(len(local), dtype=bool)
    inl[inliers] = True
    if int(inl.sum()) < 3:
        raise ValueError(f"{label}: RANSAC found only {int(inl.sum())} inliers; increase ransac_distance_m")
    return model, inl


def _refine_plane(local: np.ndarray, inl: np.ndarray, ransac_distance_m: float, label: str):
    """Least-squares refinement of a plane on its inliers, re-selecting the points within
    `ransac_distance_m` (m) of the refined plane until they no longer change (at most
    `_MAX_REFINE_ROUNDS` rounds). Returns (unit normal, n_z >= 0; centroid (local frame, m); number of
    points of the last fit)."""
    for _ in range(_MAX_REFINE_ROUNDS):
        normal, centroid, s = _svd_plane(local[inl])
        n_fit = int(inl.sum())
        if _is_degenerate(s):
            raise ValueError(f"{label}: the plane inliers are collinear; increase ransac_distance_m")
        new = np.abs((local - centroid) @ normal) <= ransac_distance_m
        if new.sum() < 3 or np.array_equal(new, inl):
            break
        inl = new
    return normal, centroid, n_fit


def _trimmed(dist: np.ndarray, z_trim: float) -> np.ndarray:
    """Boolean mask of the distances whose z-score (mean, ddof=0 std) is within +-z_trim (all if constant)."""
    if float(np.std(dist)) > 0:
        return np.abs(stats.zscore(dist)) <= z_trim
    return np.ones(len(dist), dtype=bool)


def _plane_json(normal: np.ndarray, centroid: np.ndarray) -> dict:
    """The plane as JSON: normal, d, centroid (local frame), slope (deg) and dip azimuth (deg clockwise
    from +y, None on a level plane)."""
    horiz = float(np.hypot(normal[0], normal[1]))
    return {
        "frame": "local (xyz - origin)",
        "normal": [float(v) for v in normal],
        "d": -float(normal @ centroid),
        "centroid": [float(v) for v in centroid],
        "slope_deg": math.degrees(math.atan2(horiz, abs(float(normal[2])))),
        "dip_azimuth_deg": None if horiz == 0 else math.degrees(math.atan2(normal[0], normal[1])) % 360.0,
    }


def characterize_noise(
    xyz,
    patch: dict | None = None,
    *,
    ransac_distance_m: float = 0.05,
    ransac_n: int = 3,
    iterations: int = 1000,
    z_trim: float = 2.0,
    seed: int = 0,
    name: str = "",
) -> dict[str, Any]:
    """Noise statistics of the points of ``xyz`` (N, 3), metres, float64, inside ``patch``.

    ``patch``: see :func:`select_patch`; None uses all points. ``name`` labels the result (default:
    the patch's ``"name"`` key, if any).

    Steps: RANSAC plane (Open3D ``segment_plane`` with inlier distance ``ransac_distance_m``,
    ``ransac_n`` points per sample and ``iterations`` samples, seeded with ``seed``). The inlier
    distance should be several times the noise: it only serves to find the plane, which is then
    refined by least squares (SVD about the centroid) on the inliers, re-selecting the inliers of
    the refined plane until they no longer change (at most 10 rounds); the result therefore hardly
    depends on the threshold. Then the signed distances (m, positive above the plane) of all patch
    points to the refined plane, their z-scores (``scipy.stats.zscore``: mean and ddof=0 std),
    kept = ``|z| <= z_trim``, and statistics before (all patch points) and after trimming (kept).

    Returns a dict:
        ``name``, ``patch`` (as JSON), ``n_points``, ``n_kept``, ``n_trimmed``, ``z_trim``;
        ``origin``: [x, y, z] float64 local origin subtracted from the points (zeros for local
        input); ``plane``: ``normal`` (unit, n_z >= 0), ``d`` (normal . p + d = 0 for p in the local
        frame ``xyz - origin``), ``centroid`` (local frame), ``slope_deg`` and ``dip_azimuth_deg``
        (direction of steepest descent, degrees clockwise from +y, i.e. from north for x east,
        y north; None on a level plane); ``ransac``: settings, ``n_inliers`` of the RANSAC plane and
        ``n_inliers_refined``; ``before`` / ``after``: ``n``, ``mean_m``, ``std_m`` (ddof=1),
        ``rms_m``, ``median_m``, ``robust_sigma_m`` (1.4826 * MAD), ``skewness``,
        ``skewtest_statistic``, ``skewtest_pvalue`` (None where undefined: fewer than 8 points or
        constant distances); plus the numpy arrays ``distances_m`` (float64, one per patch point,
        in the order of ``xyz[select_patch(xyz, patch)]``) and ``kept_mask`` (bool, same length).
        The arrays are not JSON-serialisable: drop them before ``json.dump`` with :func:`to_json`.

    Raises ``ValueError`` for non-finite points (naming the row), a malformed patch, bad
    settings, fewer than ``MIN_POINTS`` (50) points in the patch (naming the patch and the count)
    or collinear/coincident patch points (no plane).
    """
    pts = finite_xyz(xyz)
    if patch is not None and not name:
        name = str(patch.get("name", "")) if isinstance(patch, dict) else ""
    label = _describe(patch, name)
    _check_noise_settings(ransac_distance_m, ransac_n, iterations, z_trim)
    sel = _patch_points(pts, patch, label)
    origin = _local_origin(sel)
    local = sel - origin
    if _is_degenerate(_svd_plane(local)[2]):
        raise ValueError(f"{label}: the {len(sel)} points are collinear or coincident; no plane to fit")
    model, inl = _ransac_plane(local, ransac_distance_m, ransac_n, iterations, seed, label)
    normal, centroid, n_fit = _refine_plane(local, inl, ransac_distance_m, label)
    dist = (local - centroid) @ normal
    kept = _trimmed(dist, z_trim)
    return {
        "name": name,
        "patch": _patch_json(patch),
        "n_points": int(len(dist)),
        "n_kept": int(kept.sum()),
        "n_trimmed": int((~kept).sum()),
        "z_trim": float(z_trim),
        "origin": [float(v) for v in origin],
        "plane": _plane_json(normal, centroid),
        "ransac": {
            "distance_m": float(ransac_distance_m),
            "n": int(ransac_n),
            "iterations": int(iterations),
            "seed": int(seed),
            "plane_model": [float(v) for v in model],
            "n_inliers": int(inl.sum()),
            "n_inliers_refined": n_fit,
        },
        "before": _stats(dist),
        "after": _stats(dist[kept]),
        "distances_m": dist,
        "kept_mask": kept,
    }


def to_json(result: dict[str, Any]) -> dict[str, Any]:
    """Copy of a :func:`characterize_noise` result without its numpy arrays (``ARRAY_KEYS``), ready for ``json.dump``."""
    return {k: v for k, v in result.items() if k not in ARRAY_KEYS}


def simulated_flat_patch(
    sigma_m: float = 0.01,
    *,
    depth_m: float = -11.5,
    length_m: float = 10.0,
    seed: int = 0,
    sensor=None,
) -> np.ndarray:
    """Soundings (N, 3) float64, metres, scene frame, of one survey line over a flat seabed.

    The sensor model is :func:`sonardet.sim.mbes.scan` with the default
    :class:`~sonardet.sim.mbes.SensorConfig` (or ``sensor``, a ``SensorConfig`` or a mapping of
    sensor settings) and range noise ``sigma_m`` (metres, along the beam). The transducer runs at
    z = 0 along +x from (0, 0) to (``length_m``, 0); the seabed is a flat square triangle mesh at
    z = ``depth_m`` large enough for the whole swath. A sounding's beam angle from vertical is
    therefore ``arctan(|y| / -depth_m)``, and on this plane its range noise shows as a vertical
    (plane-normal) noise of ``sigma_m * cos(angle)``. ``seed`` seeds the noise and dropouts.
    """
    from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, straight_line, swath_half_width_m

    if not (math.isfinite(sigma_m) and sigma_m >= 0):
        raise ValueError(f"sigma_m must be a non-negative number of metres, got {sigma_m!r}")
    if not (math.isfinite(depth_m) and depth_m < 0):
        raise ValueError(f"depth_m must be below the transducer (z = 0), got {depth_m!r}")
    if not (math.isfinite(length_m) and length_m > 0):
        raise ValueError(f"length_m must be positive, got {length_m!r}")
    if sensor is None:
        sensor = SensorConfig()
    elif not isinstance(sensor, SensorConfig):
        sensor = SensorConfig.from_dict(dict(sensor))
    sensor = replace(sensor, range_sigma_m=float(sigma_m))
    altitude = -float(depth_m)
    half = swath_half_width_m(sensor, altitude) + length_m + 5.0
    xc = 0.5 * length_m
    vertices = np.array([[xc - half, -half, depth_m], [xc + half, -half, depth_m],
                         [xc + half, half, depth_m], [xc - half, half, depth_m]], dtype=np.float64)
    seabed = trimesh.Trimesh(vertices=vertices, faces=np.array([[0, 1, 2], [0, 2, 3]]), process=False)
    traj = straight_line([0.0, 0.0], [length_m, 0.0], 0.0, sensor, altitude)
    out = scan(RaycastTarget([(seabed.vertices, seabed.faces)]), traj, sensor, np.random.default_rng(seed))
    return np.ascontiguousarray(out.xyz, dtype=np.float64)
