"""Hybrid scenes: simulated reef elements implanted into a real survey's seabed.

A real MBES line supplies the seabed, its noise, its relief and its beam pattern; the simulator
supplies the objects and their ground truth. Every real sounding is a ray from the transducer to
the sounding; an implanted object that the ray meets before the seabed replaces the sounding with
the object hit (plus Gaussian range noise), so the objects are seen with the survey's own beams,
density and shadows ("same sensor geometry"), and the seabed they hide is removed.

Steps (each with its own seed derived from the config seed, "hybrid" and the scene id):
1. read the soundings (ping, beam, range, x, y, z; georeferenced, float64) and shift them to a
   local origin (whole metres below the minimum easting/northing; z is kept: transducer near 0);
2. estimate the transducer position of every ping from the soundings' slant ranges
   (:func:`estimate_sensor_positions`);
3. grid the seabed (median z per cell) into a heightfield for the physics and a coverage mask;
4. plan the objects with the synthetic scenes' layout (same class mix, arrangements and density per
   m^2) over the survey's bounding box and keep the groups that lie inside the covered seabed;
5. settle them with MuJoCo on the real seabed grid; optional burial;
6. cast the real rays against the posed object meshes (Embree) and replace the occluded soundings.

Frames and units: the scene frame is the survey's projected CRS shifted by ``origin`` (m, x east,
y north, z up as in the file). What a hybrid scene does not model: the object's own acoustic
response (intensity, footprint rounding: the sensor's `realism` profile is not applied to the
object hits) and multipath near objects.
"""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import ndimage
from scipy.optimize import least_squares

from .. import SCHEMA_VERSION
from ..seeds import config_hash, derive_seed
from ..geometry import quat_to_matrix
from ..objects import ObjectInfo
from .layout import plan_layout
from .mbes import RaycastTarget
from .scene import Scene, annotate_objects, bury_objects, class_counts, class_geometry, settle_spawns
from .seabed import Heightfield

log = logging.getLogger(__name__)

#: Columns a soundings table must have (ping index, slant range in m, georeferenced position).
REQUIRED_COLUMNS = ("ping", "range_m", "x", "y", "z")


@dataclass
class RealSurvey:
    """Soundings of one real survey line in a local frame.

    xyz: (N, 3) float64 local positions (m); ping: (N,) int ping index; beam: (N,) int beam index
    (-1 when unknown); sensor: (P, 3) float64 transducer position per ping of ``pings`` (local, m);
    pings: (P,) sorted ping indices; origin: (3,) float64 added back to get the file's coordinates;
    fit_rms_m: (P,) RMS of the range residual of each ping's transducer fit (m); source: file path;
    sha256: hex digest of the file; crs: CRS string of the file's coordinates.
    """

    xyz: np.ndarray
    ping: np.ndarray
    beam: np.ndarray
    sensor: np.ndarray
    pings: np.ndarray
    origin: np.ndarray
    fit_rms_m: np.ndarray
    source: str
    sha256: str
    crs: str

    def sensor_of(self, ping: np.ndarray) -> np.ndarray:
        """(N, 3) transducer position (local, m) of each sounding's ping."""
        return self.sensor[np.searchsorted(self.pings, ping)]


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_soundings(path) -> tuple[pd.DataFrame, str]:
    """Read a soundings table (CSV with header, gzip or not) with at least the columns
    ``ping, range_m, x, y, z`` (slant range in m; x, y, z in the survey's projected CRS, z up) and
    optionally ``beam`` and ``accepted`` (rows with accepted == 0 are left out). Errors name the file,
    the column and the row. Returns the accepted rows (float64 coordinates) and the file's SHA-256."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: soundings file not found (set hybrid_test.soundings)")
    try:
        df = pd.read_csv(path, dtype={"x": np.float64, "y": np.float64, "z": np.float64})
    except (ValueError, pd.errors.ParserError) as exc:
        raise ValueError(f"{path}: not a readable CSV soundings table: {exc}") from exc
    missing = [c for c in REQUIRED_COLUMNS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: column(s) {', '.join(missing)} missing; a hybrid scene needs "
                         f"{', '.join(REQUIRED_COLUMNS)} (found: {', '.join(map(str, df.columns))})")
    if "accepted" in df.columns:
        df = df[df["accepted"].astype(int) == 1]
    for c in REQUIRED_COLUMNS:
        vals = pd.to_numeric(df[c], errors="coerce").to_numpy(np.float64)
        bad = ~np.isfinite(vals)
        if bad.any():
            row = int(df.index[np.flatnonzero(bad)[0]])
            raise ValueError(f"{path}: column '{c}' is not a finite number on data row {row + 1} "
                             f"(line {row + 2} of the file)")
    if (df["range_m"] <= 0).any():
        row = int(df.index[np.flatnonzero(df["range_m"].to_numpy() <= 0)[0]])
        raise ValueError(f"{path}: column 'range_m' must be > 0 (data row {row + 1})")
    if len(df) < 100:
        raise ValueError(f"{path}: only {len(df)} accepted soundings; a hybrid scene needs a survey line")
    return df.reset_index(drop=True), _sha256(path)


def estimate_sensor_positions(xyz: np.ndarray, ping: np.ndarray, range_m: np.ndarray):
    """Transducer position of every ping (local frame, m) from its soundings' slant ranges.

    A ping's soundings lie on one across-track profile, so a free 3-D fit is ambiguous about a
    rotation around that profile; the fan of a roll-stabilised MBES stands vertical, so the
    transducer is sought in the vertical plane through the profile: s = c + a u + h e_z, with c the
    profile's horizontal centroid and u its horizontal direction, by Levenberg-Marquardt on
    |p_i - s| - r_i. Returns (pings (P,), positions (P, 3), rms residual (P,) m).
    """
    order = np.argsort(ping, kind="stable")
    p_sorted = ping[order]
    pings, starts = np.unique(p_sorted, return_index=True)
    ends = np.r_[starts[1:], len(order)]
    pos = np.empty((len(pings), 3))
    rms = np.empty(len(pings))
    for k, (a, b) in enumerate(zip(starts, ends)):
        idx = order[a:b]
        q, r = xyz[idx], range_m[idx]
        c = np.r_[q[:, :2].mean(0), 0.0]
        if len(idx) >= 2:
            u2 = np.linalg.svd(q[:, :2] - c[:2], full_matrices=False)[2][0]
        else:
            u2 = np.array([1.0, 0.0])
        u = np.r_[u2, 0.0]
        j = int(np.argmin(r))
        v0 = [float((q[j] - c) @ u), float(q[j, 2] + r[j])]

        def resid(v, q=q, r=r, c=c, u=u):
            s = c + v[0] * u + np.array([0.0, 0.0, v[1]])
            return np.linalg.norm(q - s, axis=1) - r

        if len(idx) >= 3:
            sol = least_squares(resid, v0, method="lm")
            v, f = sol.x, sol.fun
        else:
            v, f = np.asarray(v0), resid(v0)
        pos[k] = c + v[0] * u + np.array([0.0, 0.0, v[1]])
        rms[k] = float(np.sqrt(np.mean(f ** 2)))
    return pings, pos, rms


def read_real_survey(path, crs: str = "") -> RealSurvey:
    """Read a soundings table (:func:`read_soundings`), shift it to a local origin (whole metres below
    the minimum x and y; z unchanged) and estimate the transducer track."""
    df, sha = read_soundings(path)
    x, y, z = (df[c].to_numpy(np.float64) for c in ("x", "y", "z"))
    origin = np.array([np.floor(x.min()), np.floor(y.min()), 0.0])
    xyz = np.column_stack([x - origin[0], y - origin[1], z])
    ping = df["ping"].to_numpy(np.int64)
    beam = df["beam"].to_numpy(np.int64) if "beam" in df.columns else np.full(len(df), -1, np.int64)
    pings, sensor, rms = estimate_sensor_positions(xyz, ping, df["range_m"].to_numpy(np.float64))
    return RealSurvey(xyz, ping, beam, sensor, pings, origin, rms, str(path), sha, crs)


def seabed_grid(xyz: np.ndarray, cell_m: float, min_points: int = 3):
    """Median-z grid of the soundings (local frame, m): (Heightfield with empty cells filled from the
    nearest covered cell, covered (ny, nx) bool). Node (j, i) is the centre of cell (j, i)."""
    lo = np.floor(xyz[:, :2].min(0) / cell_m) * cell_m
    ij = np.floor((xyz[:, :2] - lo) / cell_m).astype(np.int64)
    nx, ny = (ij.max(0) + 1).tolist()
    flat = ij[:, 1] * nx + ij[:, 0]
    order = np.argsort(flat, kind="stable")
    cells, starts, counts = np.unique(flat[order], return_index=True, return_counts=True)
    zs = xyz[order, 2]
    med = np.array([np.median(zs[s:s + n]) for s, n in zip(starts, counts)])
    grid = np.full(ny * nx, np.nan)
    grid[cells] = med
    covered = np.zeros(ny * nx, bool)
    covered[cells[counts >= min_points]] = True
    grid, covered = grid.reshape(ny, nx), covered.reshape(ny, nx)
    empty = ~np.isfinite(grid)
    if empty.any():
        _, (jj, ii) = ndimage.distance_transform_edt(empty, return_indices=True)
        grid = grid[jj, ii]
    hf = Heightfield(lo[0] + 0.5 * cell_m, lo[1] + 0.5 * cell_m, cell_m, grid)
    return hf, covered


def implant(survey: RealSurvey, posed: list[tuple[np.ndarray, np.ndarray]], sigma_m: float,
            rng: np.random.Generator, min_gap_m: float = 0.005):
    """Cast every real sounding's ray (transducer -> sounding) against the posed object meshes
    [(vertices (V, 3), faces (F, 3)), ...] (local frame, m). A sounding whose ray meets an object more
    than ``min_gap_m`` before the seabed moves to the hit, with N(0, sigma_m^2) range noise along the
    ray. Returns (xyz (N, 3) float64, label (N,) int32 object index or -1)."""
    xyz = survey.xyz.copy()
    label = np.full(len(xyz), -1, np.int32)
    if not posed:
        return xyz, label
    s = survey.sensor_of(survey.ping)
    d = xyz - s
    dist = np.linalg.norm(d, axis=1)
    d /= dist[:, None]
    # Only rays whose sounding lies under an object's horizontal footprint (grown by its height: a
    # slanted ray meets a tall object far from its foot) can hit it: cast those alone.
    cand = np.zeros(len(xyz), bool)
    for v, _ in posed:
        lo, hi = v[:, :2].min(0), v[:, :2].max(0)
        grow = 1.5 * (v[:, 2].max() - v[:, 2].min()) + 0.5
        cand |= np.all((xyz[:, :2] >= lo - grow) & (xyz[:, :2] <= hi + grow), axis=1)
    idx = np.flatnonzero(cand)
    target = RaycastTarget(posed)
    rays = np.hstack([s[idx], d[idx]]).astype(np.float32)
    t, mesh, _ = target.cast(rays)
    hit = (mesh >= 0) & (t < dist[idx] - min_gap_m)
    h = idx[hit]
    noise = rng.normal(0.0, sigma_m, len(h)) if sigma_m > 0 else np.zeros(len(h))
    xyz[h] = s[h] + d[h] * (t[hit].astype(np.float64) + noise)[:, None]
    label[h] = mesh[hit]
    return xyz, label


def simulate_hybrid_scene(scene_id: str, config: dict, objects: dict[str, ObjectInfo],
                          survey: RealSurvey) -> Scene:
    """One hybrid scene: objects planned, settled and implanted into ``survey`` (module docstring).

    config: the validated workflow config (uses seed, scenes, sensor.range_sigma_m and
    hybrid_test). Deterministic for (config, scene_id, survey file). The scene's xyz are local
    (add meta["hybrid"]["origin"] for the file's coordinates); labels are object indices or -1.
    """
    sc = config["scenes"]
    hy = config["hybrid_test"]
    seed = derive_seed(config["seed"], "hybrid", scene_id)
    rngs = {k: np.random.default_rng(derive_seed(seed, k)) for k in ("layout", "physics", "sensor", "burial")}
    timings = {}

    t0 = time.perf_counter()
    hf, covered = seabed_grid(survey.xyz, hy["cell_m"])
    lo = survey.xyz[:, :2].min(0)
    hi = survey.xyz[:, :2].max(0)
    extent = (0.0, float(np.ceil(hi[0])), 0.0, float(np.ceil(hi[1])))
    # Distance (m) of every grid cell to the nearest uncovered cell: an object's group must stand on
    # covered seabed, its radius plus a margin away from the survey's edge.
    inside = ndimage.distance_transform_edt(np.pad(covered, 1))[1:-1, 1:-1] * hy["cell_m"]
    timings["grid_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    spawns, unplaced, outside = _hybrid_layout(config, objects, hf, inside, lo, hi, rngs["layout"])
    timings["layout_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    _, kept, removed, phys = settle_spawns(scene_id, spawns, objects, hf, sc["physics"], rngs["physics"],
                                           (lo[0], hi[0], lo[1], hi[1]))
    kept, buried = bury_objects(kept, spawns, hy["burial_m"], rngs["burial"])
    timings["physics_s"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    posed = []
    for k, t, q in kept:
        obj = objects[spawns[k].cls]
        posed.append((np.asarray(obj.mesh.vertices) @ quat_to_matrix(q).T + t, np.asarray(obj.mesh.faces)))
    xyz, label = implant(survey, posed, float(config["sensor"]["range_sigma_m"]), rngs["sensor"])
    timings["implant_s"] = time.perf_counter() - t0

    objs = annotate_objects(kept, spawns, objects, label, sc["min_points_visible"], buried)
    annotations = {"objects": objs, "removed": removed, "unplaced": unplaced, "rocks": [], "physics": phys}
    meta = _hybrid_meta(scene_id, config, seed, extent, survey, xyz, label, covered, outside, annotations, timings)
    line = np.zeros(len(xyz), np.int32)
    return Scene(xyz, survey.ping.astype(np.int32), survey.beam.astype(np.int32), line, label, meta)


def _hybrid_layout(config: dict, objects: dict[str, ObjectInfo], hf, inside: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray, rng: np.random.Generator):
    """The spawns of a hybrid scene: object counts scaled from `scenes.n_objects` (per extent_m area)
    to the survey's area lo..hi (m), the layout on the seabed grid hf, then every group (pile, stack,
    cluster; a scattered object alone) dropped whose spawn is closer to uncovered seabed than its
    radius plus `hybrid_test.edge_margin_m` (inside: distance (m) of each grid cell to uncovered
    seabed). Returns (spawns, unplaced messages, number of objects dropped)."""
    sc, hy = config["scenes"], config["hybrid_test"]
    # The layout draws per class in the config's order, whatever the order of `objects`.
    classes = [c for c in config["classes"] if c in objects] + [c for c in objects if c not in config["classes"]]
    area = float((hi[0] - lo[0]) * (hi[1] - lo[1]))
    counts_cfg = dict(sc)
    scale = area / float(sc["extent_m"][0] * sc["extent_m"][1])
    counts_cfg["n_objects"] = [int(round(n * scale)) for n in sc["n_objects"]]
    counts = class_counts(counts_cfg, classes, rng) if classes else {}
    verts, radius, height = class_geometry(objects)
    spawns, unplaced = plan_layout(counts, radius, height, verts, (lo[0], hi[0], lo[1], hi[1]), sc,
                                   lambda x, y: float(hf.height_at(x, y)), rng)

    def clearance(x, y):
        i = int(np.clip(np.floor((x - hf.x0) / hf.cell_m + 0.5), 0, hf.nx - 1))
        j = int(np.clip(np.floor((y - hf.y0) / hf.cell_m + 0.5), 0, hf.ny - 1))
        return float(inside[j, i])

    # Scattered spawns (group -1) stand alone; a group (pile, stack, cluster) stays or goes as a whole.
    key = [s.group if s.group >= 0 else -1 - k for k, s in enumerate(spawns)]
    bad = {g for g, s in zip(key, spawns) if clearance(s.t[0], s.t[1]) < radius[s.cls] + hy["edge_margin_m"]}
    outside = sum(g in bad for g in key)
    spawns = [s for g, s in zip(key, spawns) if g not in bad]
    return spawns, unplaced, outside


def _hybrid_meta(scene_id: str, config: dict, seed: int, extent, survey: RealSurvey, xyz: np.ndarray,
                 label: np.ndarray, covered: np.ndarray, outside: int, annotations: dict, timings: dict) -> dict:
    """The hybrid scene's JSON metadata; annotations: its objects, removed, unplaced, rocks and
    physics entries (in this order)."""
    hy = config["hybrid_test"]
    alt = survey.sensor[:, 2].mean() - float(np.median(survey.xyz[:, 2]))
    return {
        "schema_version": SCHEMA_VERSION,
        "scene": scene_id,
        "seed": int(seed),
        "config_hash": config_hash({k: config[k] for k in ("seed", "classes", "objects", "scenes", "hybrid_test")}),
        "extent": list(extent),
        "survey": {"direction": "real", "n_lines": 1, "n_pings": int(len(survey.pings)), "altitude_m": float(alt)},
        "hybrid": {
            "source": Path(survey.source).name, "sha256": survey.sha256, "crs": survey.crs,
            "origin": [float(v) for v in survey.origin],
            "n_real_soundings": int(len(xyz)), "n_replaced": int((label >= 0).sum()),
            "sensor_fit_rms_m": float(np.median(survey.fit_rms_m)),
            "dropped_outside_coverage": int(outside),
        },
        **annotations,
        "stats": {"n_points": int(len(xyz)), "n_rays": int(len(xyz)), "n_dropped": 0,
                  "points_per_m2": float(len(xyz) / max(float(covered.sum()) * hy["cell_m"] ** 2, 1e-9))},
        "timings_s": timings,
    }
