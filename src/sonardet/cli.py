"""`sonardet` command line: the workflow's stages for use outside Snakemake.

    sonardet export-scene results/scenes/s0000.npz out.las   # open it in CloudCompare
    sonardet build-objects --config config/config.yaml --out results/objects
    sonardet simulate --config config/config.yaml --scene s0000 --out results/scenes
    sonardet detect --input survey.xyz.gz --crs EPSG:32610 --out det.json --csv det.csv --geojson det.geojson
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np


def _export_scene(args) -> int:
    from .io.pointcloud import PointCloud, write_points
    from .sim.scene import load_scene_points

    pts = load_scene_points(args.scene)
    attrs = {k: np.asarray(v) for k, v in pts.items() if k != "xyz"}
    if args.out.suffix.lower() in (".las", ".laz"):
        # LAS has no int32 'label' field of its own; keep it as an extra dimension, ping/beam/line too.
        attrs = {k: v.astype(np.int32) for k, v in attrs.items()}
    write_points(args.out, PointCloud(pts["xyz"], attrs, crs=args.crs, source=str(args.scene)))
    print(f"wrote {len(pts['xyz'])} points to {args.out}")
    return 0


def _build_objects(args) -> int:
    from .config import load_config
    from .objects import build_object, save_object

    cfg = load_config(args.config)
    for cls in cfg["classes"]:
        meta = save_object(build_object(cls, cfg["objects"]), cfg["objects"]["density_kg_m3"],
                           args.out / f"{cls}.ply", args.out / f"{cls}.json")
        print(f"{cls}: height {meta['height_m']:.3f} m, volume {meta['volume_m3']:.4f} m^3, mass {meta['mass_kg']:.0f} kg")
    return 0


def _simulate(args) -> int:
    from .config import load_config
    from .objects import load_object
    from .sim.scene import save_scene, simulate_scene

    cfg = load_config(args.config)
    objects = {c: load_object(args.objects / f"{c}.json") for c in cfg["classes"]}
    scene = simulate_scene(args.scene, cfg, objects)
    save_scene(scene, args.out / f"{args.scene}.npz", args.out / f"{args.scene}.json")
    print(json.dumps({k: scene.meta[k] for k in ("stats", "timings_s", "survey")}, indent=1))
    return 0


def _detect_inputs(results: Path, classes: list[str]):
    """Object models and template scans of `classes` from a results folder; a missing file is a
    FileNotFoundError naming it and the Snakemake target that builds it."""
    from .objects import load_object
    from .sim.templates import load_templates

    objects, templates = {}, {}
    for cls in classes:
        for f in (results / "objects" / f"{cls}.json", results / "objects" / f"{cls}.ply",
                  results / "templates" / f"{cls}.npz"):
            if not f.is_file():
                target = f"results/{f.parent.name}/{f.name}"
                raise FileNotFoundError(
                    f"{f}: missing (class {cls!r}); build it with `snakemake --cores 2 {target}` in the "
                    f"workflow folder, point --results at a folder holding objects/ and templates/, or leave "
                    f"the class out with --classes")
        objects[cls] = load_object(results / "objects" / f"{cls}.json")
        templates[cls] = load_templates(results / "templates" / f"{cls}.npz")
    return objects, templates


def _detector_params(text: str | None) -> dict | None:
    """--params: a JSON object, inline or in a .json file."""
    if text is None:
        return None
    src = "--params"
    if not text.lstrip().startswith("{"):
        path = Path(text)
        if not path.is_file():
            raise FileNotFoundError(f"--params {text}: neither a JSON object nor an existing JSON file")
        src, text = str(path), path.read_text(encoding="utf-8")
    try:
        params = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{src}: not valid JSON ({exc})") from None
    if not isinstance(params, dict):
        raise ValueError(f"{src}: expected a JSON object of detector parameters, got {type(params).__name__}")
    return params


def _detect(args) -> int:
    """`sonardet detect`: model-based detection on a survey file, outputs in the input's coordinates."""
    try:
        return _run_detect(args)
    except OSError as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        # Unreadable input, unwritable output: a message naming the file, not a traceback.
        raise ValueError(str(exc)) from None


def _run_detect(args) -> int:
    import time

    from .config import validate_config
    from .detect.model_based import ModelBasedDetector, resolve_params
    from .detect.tiling import detect_tiled, plan_tiles
    from .io.annotations import to_builtin, validate_detections
    from .io.atomic import atomic_write_text
    from .io.export import write_detections_csv, write_detections_geojson
    from .io.pointcloud import read_points
    from . import SCHEMA_VERSION

    t0 = time.perf_counter()
    classes = list(args.classes) if args.classes else list(validate_config({})["classes"])
    params = _detector_params(args.params)
    resolve_params(params, args.variant)  # an unknown key or variant fails before the slow parts
    objects, templates = _detect_inputs(args.results, classes)
    # Footprint at any yaw: twice the largest horizontal distance of a vertex from the class axis.
    footprint = max(2.0 * float(np.max(np.hypot(*np.asarray(o.mesh.vertices)[:, :2].T))) for o in objects.values())
    plan_tiles((0.0, 0.0, 0.0, 0.0), args.tile_m, args.overlap_m, footprint)  # bad tiling fails before reading
    cloud = read_points(args.input, crs=args.crs)
    xyz = cloud.xyz
    if len(xyz) == 0:
        raise ValueError(f"{args.input}: no points")
    lo, hi = xyz[:, :2].min(0), xyz[:, :2].max(0)
    tiles = plan_tiles((lo[0], lo[1], hi[0], hi[1]), args.tile_m, args.overlap_m, footprint)

    t = time.perf_counter()
    run = ModelBasedDetector(templates, objects, params, args.variant)  # class models built once, run per tile
    if len(tiles) == 1:
        dets, _ = run(xyz)
        n_tiles = 1
    else:
        logging.getLogger("sonardet.detect").info("%s: %d points over %.1f x %.1f m in %d tiles of <= %g m "
                                                  "(overlap %g m)", args.input, len(xyz), hi[0] - lo[0],
                                                  hi[1] - lo[1], len(tiles), args.tile_m, args.overlap_m)
        dets, rows = detect_tiled(xyz, run, args.tile_m, args.overlap_m, progress=True, min_overlap_m=footprint)
        n_tiles = sum(not r["skipped"] for r in rows)
    t_detect = time.perf_counter() - t

    # The detection file's scene id is the output file's stem: the project's reader
    # (io.annotations.read_detections) checks that id against the file name by default.
    frame = f"{cloud.crs} metres" if cloud.crs else "the input file's coordinates (metres, CRS unknown)"
    doc = {"schema_version": SCHEMA_VERSION, "scene": args.out.stem, "method": f"model_based_{args.variant}",
           "source": str(args.input), "crs": cloud.crs, "detections": to_builtin(dets)}
    doc = validate_detections(doc, args.out, classes, args.out.stem)
    atomic_write_text(args.out, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    if args.csv is not None:
        write_detections_csv(args.csv, dets, origin_note=f"coordinates: {frame}, as in {args.input.name}; "
                                                         "yaw_rad about +z")
    if args.geojson is not None:
        write_detections_geojson(args.geojson, dets, crs=cloud.crs)
    n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
    print(f"sonardet detect: {args.input.name}: {len(xyz)} points, {n_tiles} tile(s), {len(dets)} detection(s) "
          f"({n_acc} accepted), {args.variant}, {t_detect:.1f} s detection, {time.perf_counter() - t0:.1f} s "
          f"total, coordinates in {cloud.crs or 'the input frame'} -> {args.out}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the `sonardet` command."""
    ap = argparse.ArgumentParser(prog="sonardet", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("export-scene", help="write a scene's soundings as PLY, LAS/LAZ or XYZ text")
    p.add_argument("scene", type=Path, help="results/scenes/<id>.npz")
    p.add_argument("out", type=Path, help="output file; the suffix picks the format (.ply .las .laz .xyz .csv)")
    p.add_argument("--crs", default=None, help="CRS to record (e.g. EPSG:32633); scenes are local by default")
    p.set_defaults(func=_export_scene)
    p = sub.add_parser("build-objects", help="build the class meshes of a config")
    p.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    p.add_argument("--out", type=Path, default=Path("results/objects"))
    p.set_defaults(func=_build_objects)
    p = sub.add_parser("simulate", help="synthesize one scene")
    p.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    p.add_argument("--objects", type=Path, default=Path("results/objects"))
    p.add_argument("--scene", default="s0000")
    p.add_argument("--out", type=Path, default=Path("results/scenes"))
    p.set_defaults(func=_simulate)
    p = sub.add_parser(
        "detect", help="detect reef structures in a survey point cloud (model-based, tiled)",
        description="Model-based detection on a survey file. Coordinates are read in float64 and kept: the "
                    "outputs are in the input's coordinates (e.g. UTM metres). Surveys larger than one tile are "
                    "processed tile by tile. The JSON's scene id is the output file's stem (name the output "
                    "after the survey to keep its name).")
    p.add_argument("--input", type=Path, required=True,
                   help="point cloud: .ply .las .laz .xyz .txt .pts .csv (text also .gz) or .npz")
    p.add_argument("--out", type=Path, required=True, help="detections JSON (sonardet detection schema)")
    p.add_argument("--csv", type=Path, default=None, help="also write the detections as CSV")
    p.add_argument("--geojson", type=Path, default=None, help="also write the box footprints as GeoJSON")
    p.add_argument("--results", type=Path, default=Path("results"),
                   help="folder with objects/{cls}.json|.ply and templates/{cls}.npz (default: results)")
    p.add_argument("--variant", choices=("ours", "paper"), default="ours", help="detector variant (default: ours)")
    p.add_argument("--params", default=None,
                   help="detector parameter overrides: a JSON object or a .json file (keys of "
                        "sonardet.detect.model_based.DEFAULTS / PAPER)")
    p.add_argument("--tile-m", type=float, default=40.0, help="largest tile side in metres (default: 40)")
    p.add_argument("--overlap-m", type=float, default=3.0,
                   help="tile overlap in metres, at least the largest object footprint (default: 3)")
    p.add_argument("--crs", default=None,
                   help="CRS of the input coordinates when the file carries none (e.g. EPSG:32610)")
    p.add_argument("--classes", nargs="+", default=None, help="classes to detect (default: the config's classes)")
    p.set_defaults(func=_detect)
    return ap


def main(argv=None) -> int:
    """Entry point of the `sonardet` command; returns the exit status."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"sonardet {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
