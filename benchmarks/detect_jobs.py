"""`sonardet detect` on a survey of several tiles with --jobs 1, 2, ...: seconds, soundings per second,
speed-up, and a check that every run wrote the same bytes.

The survey is cast the way the tiling tests cast theirs (`tests/test_tiling.py`): an fBm seabed with
objects of the four classes standing on it at random positions, surveyed by parallel MBES lines (Embree
ray casting with the sensor's noise and dropouts), in UTM coordinates (EPSG:32610). The method is the
default model-based one; its object models and templates come from ``--results`` when it holds them
(objects/{cls}.json|.ply, templates/{cls}.npz), else they are built here from the config (templates from a
reduced set of views, as in the tests).

    python benchmarks/detect_jobs.py [--extent-m 60] [--tile-m 20] [--jobs 1,2] [--objects 12]
                                     [--results results] [--config config/config.yaml] [--json out.json]

Run it on 2 cores for figures comparable with the README's (e.g. `taskset -c 0,1 python
benchmarks/detect_jobs.py`): with --jobs 2 the tiles share the two cores, so the speed-up is at most 2 and
less on a machine busy with other work.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np

UTM = np.array([5.5e5, 4.18e6, 0.0])
TEMPLATE_CFG = {"yaw_deg": [0, 60], "directions": ["x", "y"], "offsets_m": [-7.5, 0.0, 7.5], "altitude_m": 11.5}


def build_results(cfg: dict, root: Path) -> None:
    """Object models and (reduced) templates of the config's classes under root/objects, root/templates."""
    from sonardet.io.templates import write_templates
    from sonardet.objects import build_object, write_object
    from sonardet.sim.mbes import SensorConfig
    from sonardet.sim.templates import scan_templates

    sensor = SensorConfig.from_dict(cfg["sensor"])
    for cls in cfg["classes"]:
        m = build_object(cls, cfg["objects"])
        write_object(m, cfg["objects"]["density_kg_m3"], root / "objects" / f"{cls}.ply", root / "objects" / f"{cls}.json")
        tv = scan_templates(cls, m.mesh.vertices, m.mesh.faces, m.symmetry_order, TEMPLATE_CFG, sensor,
                            np.random.default_rng(1))
        write_templates(root / "templates" / f"{cls}.npz", tv)


def models_folder(cfg: dict, results: Path | None, tmp: Path) -> Path:
    """`results` when it holds objects/ and templates/, else tmp/results with both built here (printed)."""
    if results is not None and (results / "templates").is_dir():
        return results
    t = time.perf_counter()
    build_results(cfg, tmp / "results")
    print(f"object models and reduced templates built in {time.perf_counter() - t:.1f} s")
    return tmp / "results"


def place_objects(radii_m: np.ndarray, extent_m: float, gap_m: float | None, rng) -> np.ndarray:
    """Centres (len(radii_m), 2) in [3, extent_m - 3] m: independent uniform draws when gap_m is None,
    else rejection sampling so that no two objects' footprint circles (radius radii_m) come closer than
    gap_m (ValueError naming --objects when the extent cannot hold them after 200 tries per object)."""
    n = len(radii_m)
    if gap_m is None:
        return rng.uniform(3.0, extent_m - 3.0, (n, 2))
    cell = 2.0 * float(np.max(radii_m, initial=0.0)) + gap_m
    grid: dict[tuple[int, int], list[int]] = {}
    out = np.zeros((n, 2))
    for k in range(n):
        for _ in range(200):
            c = rng.uniform(3.0, extent_m - 3.0, 2)
            ci, cj = (int(v // cell) for v in c)
            near = [m for di in (-1, 0, 1) for dj in (-1, 0, 1) for m in grid.get((ci + di, cj + dj), ())]
            if all(np.hypot(*(c - out[m])) >= radii_m[k] + radii_m[m] + gap_m for m in near):
                break
        else:
            raise ValueError(f"--objects {n}: no room for object {k} on {extent_m:g} m x {extent_m:g} m with "
                             f"{gap_m:g} m gaps; ask for fewer objects or a larger extent")
        out[k] = c
        grid.setdefault((ci, cj), []).append(k)
    return out


def cast_survey(cfg: dict, results: Path, extent_m: float, n_objects: int, seed: int,
                gap_m: float | None = None) -> tuple[np.ndarray, list]:
    """An extent_m x extent_m survey with n_objects objects on the seabed (classes in turn, random yaw;
    placed independently, or `gap_m` apart: `place_objects`): soundings (N, 3) in UTM metres and the
    objects as (class, [x, y, z] of the mesh origin in UTM metres, yaw in rad)."""
    from sonardet.geometry import quat_from_yaw, quat_to_matrix
    from sonardet.objects import read_object
    from sonardet.sim.mbes import RaycastTarget, SensorConfig, scan, survey_lines
    from sonardet.sim.seabed import make_seabed

    rng = np.random.default_rng(seed)
    sensor = SensorConfig.from_dict(cfg["sensor"])
    hf = make_seabed((extent_m, extent_m), cell_m=0.2, mean_depth_m=-11.5, slope_deg=1.5, amplitude_m=0.1, rng=rng)
    classes = list(cfg["classes"])
    objs = {c: read_object(results / "objects" / f"{c}.json") for c in classes}
    order = [classes[k % len(classes)] for k in range(n_objects)]
    radii = np.array([float(np.max(np.hypot(*np.asarray(objs[c].mesh.vertices)[:, :2].T))) for c in order])
    yaws = rng.uniform(0, 2 * np.pi, n_objects) if gap_m is not None else None
    centres = place_objects(radii, extent_m, gap_m, rng) if gap_m is not None else None
    meshes = [(hf.vertices(), hf.faces())]
    placed = []
    for k, c in enumerate(order):
        yaw = rng.uniform(0, 2 * np.pi) if yaws is None else yaws[k]
        v = np.asarray(objs[c].mesh.vertices) @ quat_to_matrix(quat_from_yaw(yaw)).T
        x, y = centres[k] if centres is not None else rng.uniform(3.0, extent_m - 3.0, 2)
        base = v[:, 2] < v[:, 2].min() + 0.05
        z = float(np.max(hf.height_at(v[base, 0] + x, v[base, 1] + y))) - v[:, 2].min()
        meshes.append((v + [x, y, z], np.asarray(objs[c].mesh.faces)))
        placed.append((c, [float(x + UTM[0]), float(y + UTM[1]), float(z + UTM[2])], float(yaw)))
    traj = survey_lines((0, extent_m, 0, extent_m), "x", 0.0, 11.5, 0.3, sensor, run_in_m=1.0)
    xyz = scan(RaycastTarget(meshes), traj, sensor, np.random.default_rng(seed + 1)).xyz
    inside = np.all((xyz[:, :2] >= 0) & (xyz[:, :2] <= extent_m), axis=1)
    return xyz[inside] + UTM, placed


def run_detect(survey: Path, results: Path, out: Path, tile_m: float, jobs: int) -> tuple[float, str]:
    """`sonardet detect --jobs jobs` on the survey: (wall seconds, its summary line)."""
    from sonardet.cli import main

    argv = ["detect", "--input", str(survey), "--out", str(out), "--csv", str(out.with_suffix(".csv")),
            "--results", str(results), "--crs", "EPSG:32610", "--tile-m", str(tile_m), "--jobs", str(jobs),
            "--quiet"]
    buf = io.StringIO()
    t = time.perf_counter()
    with contextlib.redirect_stdout(buf):
        rc = main(argv)
    seconds = time.perf_counter() - t
    if rc != 0:
        raise SystemExit(f"sonardet detect --jobs {jobs} failed (exit {rc})")
    return seconds, buf.getvalue().strip()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--extent-m", type=float, default=60.0, help="survey side in metres (default 60)")
    ap.add_argument("--tile-m", type=float, default=20.0, help="tile side in metres (default 20: 3 x 3 tiles)")
    ap.add_argument("--objects", type=int, default=12, help="objects on the seabed (default 12)")
    ap.add_argument("--jobs", default="1,2",
                    help="comma-separated --jobs values to time, in this order, repeats allowed (default 1,2)")
    ap.add_argument("--results", type=Path, default=None,
                    help="folder holding objects/ and templates/ (default: built here from the config)")
    ap.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--json", default=None, help="write the numbers to this JSON file")
    args = ap.parse_args()
    from sonardet.config import read_config
    from sonardet.io.points import PointCloud, write_points

    cfg = read_config(args.config)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        results = models_folder(cfg, args.results, tmp)
        t = time.perf_counter()
        xyz, _ = cast_survey(cfg, results, args.extent_m, args.objects, args.seed)
        survey = tmp / "survey.npz"
        write_points(survey, PointCloud(xyz, crs="EPSG:32610"))
        print(f"survey: {len(xyz)} soundings over {args.extent_m:g} m x {args.extent_m:g} m, {args.objects} objects, "
              f"cast in {time.perf_counter() - t:.1f} s; tiles of {args.tile_m:g} m; "
              f"{os.cpu_count()} CPU(s) visible, affinity {len(os.sched_getaffinity(0))} core(s)")
        rows, outputs = [], []
        for i, jobs in enumerate(int(j) for j in args.jobs.split(",")):
            out = tmp / f"run{i}_jobs{jobs}" / "survey.json"
            out.parent.mkdir()
            seconds, line = run_detect(survey, results, out, args.tile_m, jobs)
            m = re.search(r"([\d.]+) s detection \((\d+) soundings/s", line)
            rows.append({"jobs": jobs, "wall_seconds": seconds, "detect_seconds": float(m.group(1)),
                         "soundings_per_second": int(m.group(2)), "n_soundings": len(xyz)})
            outputs.append([out.read_bytes(), out.with_suffix(".csv").read_bytes()])
            print(f"--jobs {jobs}: {line}")
        base = rows[0]["detect_seconds"]
        for r in rows:
            r["speedup"] = base / r["detect_seconds"] if r["detect_seconds"] > 0 else float("nan")
            print(f"--jobs {r['jobs']}: {r['detect_seconds']:.1f} s detection, {r['soundings_per_second']} "
                  f"soundings/s, speed-up {r['speedup']:.2f} x over --jobs {rows[0]['jobs']} "
                  f"({r['wall_seconds']:.1f} s for the whole command)")
        same = all(v == outputs[0] for v in outputs)
        print("outputs (JSON, CSV) identical across --jobs values:", same)
    if args.json:
        Path(args.json).write_text(json.dumps({"runs": rows, "identical_outputs": same}, indent=1))
    if not same:
        raise SystemExit("the outputs differ between --jobs values")


if __name__ == "__main__":
    main()
