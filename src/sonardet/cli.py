"""`sonardet` command line: the workflow's stages for use outside Snakemake.

    sonardet export-scene scenes/s0000.npz out.las   # open it in CloudCompare
    sonardet build-objects --config config/config.yaml --out objects
    sonardet simulate --config config/config.yaml --objects objects --scene s0000 --out scenes
    sonardet detect --input survey.xyz.gz --crs EPSG:32610 --out det.json --csv det.csv --geojson det.geojson
    sonardet detect --method sasa_100 --model models/sasa_100/model.pt --input survey.xyz.gz --out det.json
    sonardet detect --input depths.xyz --z-positive down --crs EPSG:32610 --out det.json --las det.laz --meshes det.ply
    sonardet detect --input survey_lonlat.csv --out det.json --geojson det.geojson   # lon,lat,depth columns
    sonardet detect --input bathy_0.2m.tif --out det.json --csv det.csv               # GeoTIFF / BAG grids
    sonardet detect --input big_survey.laz --jobs 4 --out det.json                     # 4 tiles at once
    sonardet export-dataset --format openpcdet --results results --out data/custom
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import warnings
from pathlib import Path

import numpy as np


def _export_scene(args) -> int:
    from .io.points import PointCloud, write_points
    from .io.scenes import read_scene_points

    pts = read_scene_points(args.scene)
    attrs = {k: np.asarray(v) for k, v in pts.items() if k != "xyz"}
    if args.out.suffix.lower() in (".las", ".laz"):
        # LAS has no int32 'label' field of its own; keep it as an extra dimension, ping/beam/line too.
        attrs = {k: v.astype(np.int32) for k, v in attrs.items()}
    write_points(args.out, PointCloud(pts["xyz"], attrs, crs=args.crs, source=str(args.scene)))
    print(f"wrote {len(pts['xyz'])} points to {args.out}")
    return 0


def _build_objects(args) -> int:
    from .config import read_config
    from .objects import build_object, write_object

    cfg = read_config(args.config)
    for cls in cfg["classes"]:
        meta = write_object(build_object(cls, cfg["objects"]), cfg["objects"]["density_kg_m3"],
                           args.out / f"{cls}.ply", args.out / f"{cls}.json")
        print(f"{cls}: height {meta['height_m']:.3f} m, volume {meta['volume_m3']:.4f} m^3, mass {meta['mass_kg']:.0f} kg")
    return 0


def _simulate(args) -> int:
    from .config import read_config
    from .io.scenes import write_scene
    from .objects import read_object
    from .progress import progress_bar
    from .sim.scene import simulate_scene

    cfg = read_config(args.config)
    objects = {c: read_object(args.objects / f"{c}.json") for c in cfg["classes"]}
    for sid in progress_bar(args.scene, desc="simulate", unit="scene", enabled=not args.quiet):
        scene = simulate_scene(sid, cfg, objects)
        write_scene(scene, args.out / f"{sid}.npz", args.out / f"{sid}.json")
        if len(args.scene) == 1:
            print(json.dumps({k: scene.meta[k] for k in ("stats", "timings_s", "survey")}, indent=1))
        else:
            logging.getLogger("sonardet.simulate").info("%s: %d soundings, %d objects", sid, len(scene.xyz),
                                                        len(scene.meta["objects"]))
    return 0


def _export_dataset(args) -> int:
    """`sonardet export-dataset`: the synthetic dataset in another detector framework's layout."""
    from .io.openpcdet import export_openpcdet
    from .progress import progress_bar
    from .sim.dataset import read_split

    cfg = _config(args)
    scenes = args.scenes if args.scenes is not None else args.results / "scenes"
    splits_dir = args.splits if args.splits is not None else args.results / "splits"
    names = [n for n in ("train", "dev", "test") if (splits_dir / f"{n}.txt").is_file()]
    if "train" not in names:
        raise FileNotFoundError(f"{splits_dir / 'train.txt'}: missing; make the splits with `snakemake --cores 2 "
                                f"results/splits/train.txt` or point --splits at a folder of <split>.txt files")
    names += sorted(p.stem for p in splits_dir.glob("train_*.txt"))
    splits = {n: read_split(splits_dir / f"{n}.txt") for n in names}
    info = export_openpcdet(scenes, splits, args.out, classes=cfg["classes"], feature=args.feature,
                            progress=lambda ids: progress_bar(ids, desc="export", unit="scene", enabled=not args.quiet))
    sets = ", ".join(f"{k} {v}" for k, v in info["image_sets"].items())
    print(f"sonardet export-dataset: {len(info['origins'])} scenes from {scenes} in OpenPCDet's custom layout -> "
          f"{args.out} (ImageSets: {sets}; dev -> val)")
    return 0


def _detect_inputs(results: Path, classes: list[str], kinds) -> tuple[dict | None, dict | None]:
    """Object models and template scans of `classes` from a results folder, as far as the method
    needs them (`kinds`: its resources); a missing file is a FileNotFoundError naming it and the
    Snakemake target that builds it."""
    from .io.templates import read_templates
    from .objects import read_object

    if "objects" not in kinds and "templates" not in kinds:
        return None, None
    objects, templates = {}, {}
    for cls in classes:
        need = [results / "objects" / f"{cls}.json", results / "objects" / f"{cls}.ply"]
        if "templates" in kinds:
            need.append(results / "templates" / f"{cls}.npz")
        for f in need:
            if not f.is_file():
                target = "/".join(f.parts[-3:])
                raise FileNotFoundError(
                    f"{f}: missing (class {cls!r}); build it with `snakemake --cores 2 {target}` in the "
                    f"workflow folder, point --results at a folder holding objects/ and templates/, or leave "
                    f"the class out with --classes")
        objects[cls] = read_object(results / "objects" / f"{cls}.json")
        if "templates" in kinds:
            templates[cls] = read_templates(results / "templates" / f"{cls}.npz")
    return objects, (templates if "templates" in kinds else None)


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


def _detect_method(args, cfg: dict):
    """The method of `sonardet detect`, with --params on top of its settings (validated)."""
    from . import methods

    method = methods.get(args.method, cfg)
    params = _detector_params(args.params)
    if params:
        method = method.with_settings(params=params)
    methods.family(method.family).check_params(method)  # an unknown key fails before the slow parts
    return method


def _footprint_m(objects: dict | None, classes: list[str], cfg: dict) -> float:
    """Largest object footprint (m, any yaw): from the object models when loaded, else from the class
    specs at the config's parameters."""
    from .objects import footprint_radius_m

    if objects:
        return max(2.0 * float(np.max(np.hypot(*np.asarray(o.mesh.vertices)[:, :2].T))) for o in objects.values())
    return max(2.0 * footprint_radius_m(c, cfg["objects"]) for c in classes)


def _class_colours(classes: list[str]) -> dict[str, str]:
    """Report colour of each class (its spec), for the posed meshes."""
    from .objects import classes as class_specs

    return {c: class_specs.get(c).colour for c in classes}


def _detect_run(args, cfg: dict, classes: list[str]):
    """The method of `sonardet detect`, loaded (sonardet.survey.DetectRun), with the object models."""
    from . import methods
    from .methods import Resources
    from .survey import DetectRun, available_cores, plan_tiles

    method = _detect_method(args, cfg)
    kinds = set(method.resources) | ({"objects"} if args.meshes is not None else set())
    objects, templates = _detect_inputs(args.results, classes, kinds)
    footprint = _footprint_m(objects, classes, cfg)
    plan_tiles((0.0, 0.0, 0.0, 0.0), args.tile_m, args.overlap_m, footprint)  # bad tiling fails before loading
    model = args.model if args.model is not None else args.results / "models" / method.name / "model.pt"
    if "model" in method.resources and not model.is_file():
        raise FileNotFoundError(f"{model}: no trained model for {method.name}; train it with `snakemake --cores 2 "
                                f"{model}` in the workflow folder or give its file with --model")
    # Default threads: the model-based detector's fits give the same detections on any number of threads,
    # so it takes every core (a tile worker process keeps one); a learned method keeps PyTorch on one.
    threads = args.threads if args.threads is not None else (available_cores() if method.family == "model_based" else 1)
    detector = methods.family(method.family).load(method, Resources(
        objects=objects, templates=templates, model_path=model if "model" in method.resources else None,
        threads=threads))
    return DetectRun(method.name, detector, classes, args.tile_m, args.overlap_m, footprint, args.all_hypotheses,
                     keep_fliers=args.keep_fliers, objects=objects, colours=_class_colours(classes),
                     progress=not args.quiet, jobs=args.jobs if args.jobs is not None else available_cores())


def _run_detect(args) -> int:
    import time

    from .survey import OutputPaths, SurveySource, detect_survey_file
    from .usage import compilations_note, numba_compilations

    t0 = time.perf_counter()
    if args.jobs is not None and args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs}: the number of tiles detected at once must be at least 1 (default: "
                         f"all CPU cores)")
    if args.threads is not None and args.threads < 1:
        raise ValueError(f"--threads {args.threads}: a detection needs at least 1 thread")
    cfg = _config(args)
    classes = list(args.classes) if args.classes else list(cfg["classes"])
    cfg["classes"] = classes
    paths = OutputPaths.of(json=args.out, csv=args.csv, geojson=args.geojson, geojson_crs=args.geojson_crs,
                           las=args.las, meshes=args.meshes)
    paths.check_suffixes()  # the CRS is known once the file is read
    run = _detect_run(args, cfg, classes)
    source = SurveySource.of(args.input, crs=args.crs, z_positive=args.z_positive, columns=args.columns)
    # The JSON's scene id is the output file's stem: the project's reader (io.annotations.read_detections)
    # checks that id against the file name by default.
    res = detect_survey_file(source, run, paths, name=args.out.stem)
    dets = res.doc["detections"]
    n_acc = sum(bool(d.get("extras", {}).get("accepted", True)) for d in dets)
    kept = "all hypotheses" if args.all_hypotheses else f"{res.n_hypotheses - len(dets)} rejected hypotheses left out"
    crs = res.survey.cloud.crs
    frame = crs or "the input frame"
    if res.survey.projection is not None:
        frame = f"{crs} (projected from {res.survey.input_crs})"
    jobs = f", {res.jobs} jobs" if res.jobs > 1 else ""
    print(f"sonardet detect: {args.input.name}: {len(res.survey.cloud)} points, {res.n_tiles} tile(s), {len(dets)} "
          f"detection(s) ({n_acc} accepted; {kept}), {run.method}, {res.detect_seconds:.1f} s detection "
          f"({res.soundings_per_second:.0f} soundings/s{jobs}), {time.perf_counter() - t0:.1f} s total, coordinates "
          f"in {frame} -> {args.out}")
    note = compilations_note(numba_compilations())  # this process's; tile workers compile (and cache) their own
    if note:
        print(f"sonardet detect: {note}")
    return 0


def _config(args) -> dict:
    """The validated config of a command: --config's file, or the defaults (with --plugins)."""
    from .config import read_config, validate_config

    if getattr(args, "config", None) is not None:
        cfg = read_config(args.config)
        if getattr(args, "plugins", None):
            cfg = validate_config({**cfg, "plugins": list(cfg["plugins"]) + list(args.plugins)}, source=str(args.config))
        return cfg
    return validate_config({"plugins": list(getattr(args, "plugins", None) or [])}, source="defaults")


def _add_quiet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", action="store_true",
                   help="no progress bars and no informational log lines (bars are drawn only on a terminal anyway)")


def _add_export_dataset_parser(sub) -> None:
    """The `export-dataset` subcommand."""
    p = sub.add_parser("export-dataset", help="write the synthetic dataset in a detector framework's layout",
                       description="The simulated scenes and splits in OpenPCDet's custom-dataset layout "
                                   "(points/*.npy, labels/*.txt, ImageSets/train|val|test.txt with dev as val), "
                                   "so any OpenPCDet detector trains on them.")
    p.add_argument("--format", choices=("openpcdet",), default="openpcdet", help="target layout (openpcdet)")
    p.add_argument("--results", type=Path, default=Path("results"),
                   help="workflow results folder holding scenes/ and splits/ (default: results)")
    p.add_argument("--scenes", type=Path, default=None, help="scene folder (default: <results>/scenes)")
    p.add_argument("--splits", type=Path, default=None,
                   help="folder of train.txt, dev.txt, test.txt, train_<f>.txt (default: <results>/splits)")
    p.add_argument("--out", type=Path, required=True, help="output folder (OpenPCDet's data/custom)")
    p.add_argument("--feature", choices=("zero", "beam"), default="zero",
                   help="4th point column: zero (OpenPCDet's intensity slot) or beam (distance from the swath "
                        "centre, 0..1)")
    p.add_argument("--config", type=Path, default=None, help="workflow config naming the classes (default: built-in)")
    p.add_argument("--plugins", nargs="+", default=None, help="plugin modules registering more classes")
    _add_quiet(p)
    p.set_defaults(func=_export_dataset)


def _add_detect_parser(sub) -> None:
    """The `detect` subcommand."""
    p = sub.add_parser(
        "detect", help="detect reef structures in a survey point cloud (any registered method, tiled)",
        description="Detection with any registered method (training-free or learned) on a survey file. Coordinates are read in float64 and kept: the "
                    "outputs are in the input's coordinates (e.g. UTM metres). Surveys larger than one tile are "
                    "processed tile by tile. The JSON's scene id is the output file's stem (name the output "
                    "after the survey to keep its name).")
    p.add_argument("--input", type=Path, required=True,
                   help="survey file: soundings .las .laz .xyz .txt .pts .csv (text also .gz) .ply .npz, or gridded "
                        "bathymetry .tif/.tiff (GeoTIFF) or .bag (cells of at most 0.25 m)")
    p.add_argument("--out", type=Path, required=True, help="detections JSON (sonardet detection schema)")
    p.add_argument("--csv", type=Path, default=None,
                   help="also write the detections as CSV (header line, lon/lat columns when the CRS is known; "
                        "metadata in <csv>.json)")
    p.add_argument("--geojson", type=Path, default=None,
                   help="also write the box footprints as RFC 7946 GeoJSON (WGS 84 longitude/latitude; needs the CRS)")
    p.add_argument("--geojson-crs", type=Path, default=None, metavar="PATH",
                   help="also write the box footprints as GeoJSON in the input's CRS (named in a 'crs' member, "
                        "as GDAL/QGIS read it)")
    p.add_argument("--las", type=Path, default=None,
                   help="also write the input soundings as a classified .las/.laz (ASPRS class 2 seabed, 43 inside a "
                        "detected box; extra bytes object_id, cls) for CloudCompare")
    p.add_argument("--meshes", type=Path, default=None,
                   help="also write the detected objects' posed meshes as one .ply (float64 vertices in the CRS, "
                        "coloured by class)")
    p.add_argument("--z-positive", choices=("up", "down"), default=None,
                   help="direction of the file's vertical values: up (elevations) or down (depths, read as "
                        "z = -depth); default: from the column name (depth is down), else up")
    p.add_argument("--columns", default=None, metavar="NAMES",
                   help="text files: comma-separated column names in file order, e.g. x,y,depth or lon,lat,z,ping "
                        "(x/easting, y/northing, z/elevation, depth, lon/lat; other names become attributes)")
    p.add_argument("--results", type=Path, default=Path("results"),
                   help="folder with objects/{cls}.json|.ply and templates/{cls}.npz (default: results)")
    p.add_argument("--method", default="model_based_ours",
                   help="detection method: any registered one, e.g. model_based_ours (default), model_based_paper, "
                        "sasa_100 (needs its trained model: --model)")
    p.add_argument("--model", type=Path, default=None,
                   help="trained model file of a learned method (default: <results>/models/<method>/model.pt)")
    p.add_argument("--config", type=Path, default=None,
                   help="workflow config whose settings the method uses (default: the built-in defaults)")
    p.add_argument("--plugins", nargs="+", default=None,
                   help="plugin modules (.py files or module names) registering more methods or classes")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads of one detection: PyTorch's of a learned method (default 1), the worker threads "
                        "of model-based `ours` (default: all CPU cores this process may use; the same detections on "
                        "any number); with --jobs above 1 each tile process uses one")
    p.add_argument("--jobs", type=int, default=None, metavar="N",
                   help="tiles detected at once, each in its own process on one thread (default: all CPU cores "
                        "this process may use; a survey of one tile runs in one process); the detections are "
                        "those of --jobs 1")
    p.add_argument("--all-hypotheses", action="store_true",
                   help="also write the hypotheses the method did not accept as objects (model-based `ours` "
                        "keeps them at a low score, extras.accepted false); default: accepted objects only")
    p.add_argument("--params", default=None,
                   help="parameter overrides of the method: a JSON object or a .json file (model-based: keys of "
                        "sonardet.detect.model_based.DEFAULTS / PAPER; SASA: its inference keys)")
    # sonardet.survey.DEFAULT_TILE_M (not imported here: the survey package is imported only when a
    # survey is read, to keep `sonardet --help` fast; a test checks the two agree).
    p.add_argument("--tile-m", type=float, default=50.0, help="largest tile side in metres (default: 50)")
    p.add_argument("--overlap-m", type=float, default=3.0,
                   help="tile overlap in metres, at least the largest object footprint (default: 3)")
    p.add_argument("--crs", default=None,
                   help="CRS of the input coordinates when the file carries none (e.g. EPSG:32610; a geographic one "
                        "such as EPSG:4326 is projected to the data's UTM zone, lon/lat columns are EPSG:4326)")
    p.add_argument("--keep-fliers", action="store_true",
                   help="keep isolated far soundings (at most 100 soundings more than 100 m from the rest); by "
                        "default they are left out and reported")
    p.add_argument("--classes", nargs="+", default=None, help="classes to detect (default: the config's classes)")
    _add_quiet(p)
    p.set_defaults(func=_detect)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the `sonardet` command."""
    ap = argparse.ArgumentParser(prog="sonardet", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("export-scene", help="write a scene's soundings as PLY, LAS/LAZ or XYZ text")
    p.add_argument("scene", type=Path, help="a scene's soundings file, <id>.npz")
    p.add_argument("out", type=Path, help="output file; the suffix picks the format (.ply .las .laz .xyz .csv)")
    p.add_argument("--crs", default=None, help="CRS to record (e.g. EPSG:32633); scenes are local by default")
    _add_quiet(p)
    p.set_defaults(func=_export_scene)
    p = sub.add_parser("build-objects", help="build the class meshes of a config")
    p.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    p.add_argument("--out", type=Path, required=True, help="folder for {cls}.ply and {cls}.json")
    _add_quiet(p)
    p.set_defaults(func=_build_objects)
    p = sub.add_parser("simulate", help="synthesize one scene")
    p.add_argument("--config", type=Path, default=Path("config/config.yaml"))
    p.add_argument("--objects", type=Path, required=True, help="folder with the objects' {cls}.json and {cls}.ply")
    p.add_argument("--scene", nargs="+", default=["s0000"], help="scene id(s) (default s0000)")
    p.add_argument("--out", type=Path, required=True, help="folder for {scene}.npz and {scene}.json")
    _add_quiet(p)
    p.set_defaults(func=_simulate)
    _add_export_dataset_parser(sub)
    _add_detect_parser(sub)
    return ap


def main(argv=None) -> int:
    """Entry point of the `sonardet` command; returns the exit status."""
    from tqdm.contrib.logging import logging_redirect_tqdm

    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("sonardet").setLevel(logging.WARNING if getattr(args, "quiet", False) else logging.NOTSET)
    try:
        with warnings.catch_warnings(), logging_redirect_tqdm():  # log lines above a progress bar
            warnings.showwarning = _log_warning
            return args.func(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"sonardet {args.command}: error: {exc}", file=sys.stderr)
        return 2


def _log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Show a library warning (e.g. a file whose z looks positive down) as one log line of the command."""
    logging.getLogger("sonardet").warning("%s", message)


if __name__ == "__main__":
    sys.exit(main())
