"""`sonardet` command line: the workflow's stages for use outside Snakemake.

    sonardet export-scene results/scenes/s0000.npz out.las   # open it in CloudCompare
    sonardet build-objects --config config/config.yaml --out results/objects
    sonardet simulate --config config/config.yaml --scene s0000 --out results/scenes
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
