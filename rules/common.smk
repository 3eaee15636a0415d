# Helper functions shared by the rules: config validation, class lists, output paths.
import os
import sys

from snakemake.exceptions import WorkflowError

# The library lives in src/; importable here even when the package is not installed. Each job's
# script inserts the same path itself (e.g. in a rule's conda env).
sys.path.insert(0, os.path.join(workflow.basedir, "src"))

from sonardet.config import (
    ConfigError,
    realism_effect_config,
    realism_effects,
    realism_test_config,
    validate_config,
)
from sonardet.sim.dataset import make_splits, scene_ids, split_names

try:
    _validated = validate_config(config, source="workflow config")
except ConfigError as exc:
    raise WorkflowError(str(exc))
config.clear()
config.update(_validated)

CLASSES = config["classes"]
SCENES = scene_ids(config["scenes"]["n_scenes"])
SPLITS = split_names(config["split"]["fractions"])
# The split is a pure function of the config, so the DAG knows the test scenes without a checkpoint;
# the split rule writes the same lists to results/splits/ for users and other tools.
SPLIT = make_splits(
    SCENES,
    config["split"]["n_test"],
    config["split"]["n_val"],
    config["split"]["fractions"],
    config["seed"],
)
#: Evaluation datasets: name -> scene ids, and the folder holding their scene files.
DATASETS = {"synthetic": SPLIT["test"]}
DATASET_DIRS = {"synthetic": "results/scenes"}
if config["realism_test"]["enabled"]:
    DATASETS["realism"] = SPLIT["test"]
    DATASET_DIRS["realism"] = "results/realism/scenes"
HYBRID = config["hybrid_test"]["enabled"] and os.path.exists(
    config["hybrid_test"]["soundings"]
)
if config["hybrid_test"]["enabled"] and not HYBRID:
    print(
        f"sonardet: hybrid_test.soundings {config['hybrid_test']['soundings']} not found: the "
        "hybrid test set is left out of this run (set hybrid_test.soundings to a real soundings "
        "table, or hybrid_test.enabled: false to silence this)",
        file=sys.stderr,
    )
if HYBRID:
    DATASETS["hybrid"] = scene_ids(config["hybrid_test"]["n_scenes"])
    DATASET_DIRS["hybrid"] = "results/hybrid/scenes"
FRACTIONS = [int(f) for f in config["split"]["fractions"]]
#: Methods: model_based_{variant} and sasa_{fraction}.
METHODS = [f"model_based_{v}" for v in config["model_based"]["variants"]] + (
    [f"sasa_{f}" for f in FRACTIONS] if config["sasa"]["enabled"] else []
)
#: SASA trained with domain randomisation: sasa_dr_{fraction} (compared with sasa_{fraction}).
DR_METHODS = (
    [f"sasa_dr_{f}" for f in config["domain_randomisation"]["fractions"]]
    if config["sasa"]["enabled"] and config["domain_randomisation"]["enabled"]
    else []
)
#: One-at-a-time realism ablation: effect -> dataset name; its scenes are the first test scenes.
REALISM_EFFECT_KEYS = realism_effects(config)
REALISM_EFFECTS = {e: f"realism_{e}" for e in REALISM_EFFECT_KEYS}
REALISM_ABLATION_SCENES = SPLIT["test"][: config["realism_ablation"]["n_scenes"]]
for _effect, _dataset in REALISM_EFFECTS.items():
    DATASETS[_dataset] = REALISM_ABLATION_SCENES
    DATASET_DIRS[_dataset] = f"results/realism_ablation/{_effect}/scenes"
#: Datasets of the realism ablation's summary: plain sensor, every effect, one effect at a time.
REALISM_ABLATION_DATASETS = ["synthetic", "realism"] + list(REALISM_EFFECTS.values())
#: Datasets evaluated on their own (the ablation datasets are evaluated together, in one job).
EVAL_DATASETS = [d for d in DATASETS if d not in REALISM_EFFECTS.values()]
#: Ablation grid points by name, and the test scenes they run on.
ABLATION = (
    {p["name"]: p for p in config["ablation"]["points"]}
    if config["ablation"]["enabled"]
    else {}
)
ABLATION_SCENES = SPLIT["test"][: config["ablation"]["n_scenes"]]


wildcard_constraints:
    cls="|".join(CLASSES),
    scene=r"s\d{4}",
    dataset="|".join(DATASETS),
    variant="paper|ours",
    fraction=r"\d+",
    method=r"model_based_(paper|ours)|sasa_\d+|sasa_dr_\d+",
    model=r"sasa_\d+|sasa_dr_\d+",
    effect="|".join(REALISM_EFFECTS) or "none",
    point=r"[A-Za-z0-9_-]+",


def object_files(ext):
    """results/objects/{cls}.{ext} for every configured class."""
    return expand("results/objects/{cls}.{ext}", cls=CLASSES, ext=ext)


def template_files():
    """results/templates/{cls}.npz for every configured class."""
    return expand("results/templates/{cls}.npz", cls=CLASSES)


def scene_files(ext):
    """results/scenes/{scene}.{ext} for every scene of the dataset."""
    return expand("results/scenes/{scene}.{ext}", scene=SCENES, ext=ext)


def dataset_scene_files(dataset, ext):
    """Scene files of an evaluation dataset."""
    return expand(
        "{dir}/{scene}.{ext}",
        dir=DATASET_DIRS[dataset],
        scene=DATASETS[dataset],
        ext=ext,
    )


def dataset_scene_file(dataset, scene, ext):
    """One scene file of an evaluation dataset."""
    return f"{DATASET_DIRS[dataset]}/{scene}.{ext}"


def split_scene_files(name, ext):
    """Scene files of a split (train, val, test, train_{fraction})."""
    return expand("results/scenes/{scene}.{ext}", scene=SPLIT[name], ext=ext)


def eval_files(methods=None):
    """metrics.json of every method (default: METHODS and DR_METHODS) on every evaluation dataset."""
    return expand(
        "results/eval/{method}/{dataset}/metrics.json",
        method=METHODS + DR_METHODS if methods is None else methods,
        dataset=EVAL_DATASETS,
    )


def detection_files(method, dataset):
    """Detection files of a method on every scene of a dataset."""
    return expand(
        "results/detections/{method}/{dataset}/{scene}.json",
        method=method,
        dataset=dataset,
        scene=DATASETS[dataset],
    )


def ablation_point_inputs(wildcards):
    """Scenes, objects and templates of a grid point; SASA points also need their training scenes."""
    point = ABLATION[wildcards.point]
    inputs = {
        "scenes": expand("results/scenes/{scene}.npz", scene=ABLATION_SCENES),
        "labels": expand("results/scenes/{scene}.json", scene=ABLATION_SCENES),
        "meta": object_files("json"),
        "meshes": object_files("ply"),
        "templates": template_files(),
    }
    if point["method"] == "sasa":
        inputs["train"] = split_scene_files(f"train_{point['fraction']}", "npz")
        inputs["train_labels"] = split_scene_files(f"train_{point['fraction']}", "json")
    return inputs


def ablation_base_params(point):
    """The configured hyper-parameters a grid point starts from (only its own method's, so that a
    change of another method's settings does not rerun the point)."""
    if point["method"] == "sasa":
        return {k: config["sasa"][k] for k in ("preset", "params")}
    return config["model_based"][point["method"][len("model_based_") :]]


def ablation_files():
    """Result file of every ablation grid point and of the default-settings reference."""
    if not ABLATION:
        return []
    return expand("results/ablation/points/{point}.json", point=ABLATION) + [
        "results/ablation/reference.json"
    ]


NOISE = config["noise"]["enabled"] and os.path.exists(config["noise"]["survey"])
if config["noise"]["enabled"] and not NOISE:
    print(
        f"sonardet: noise.survey {config['noise']['survey']} not found: the noise "
        "characterisation is left out of this run (set noise.survey to a real survey file, "
        "or noise.enabled: false to silence this)",
        file=sys.stderr,
    )


#: Report tables (stem -> caption file) and figures (name -> caption file), written by rule report.
REPORT_TABLES = (
    ["dataset", "comparison", "fractions", "timing"]
    + (["comparison_realism"] if "realism" in DATASETS else [])
    + (["ablation"] if ABLATION else [])
    + (["noise"] if NOISE else [])
    + (["comparison_hybrid"] if "hybrid" in DATASETS else [])
    + (["realism_ablation"] if REALISM_EFFECTS else [])
    + (["domain_randomisation"] if DR_METHODS else [])
)
REPORT_FIGURES = (
    ["topview", "poses3d", "pr_curves", "dataset_example"]
    + (["loss_curves"] if config["sasa"]["enabled"] else [])
    + (["pareto"] if ABLATION else [])
    + (["hybrid_example"] if "hybrid" in DATASETS else [])
)


def report_files():
    """Every table (csv, md, tex), figure and the summary README written by rule report."""
    return (
        expand(
            "results/report/tables/{table}.{ext}",
            table=REPORT_TABLES,
            ext=["csv", "md", "tex"],
        )
        + expand("results/report/figures/{figure}.png", figure=REPORT_FIGURES)
        + ["results/README.md"]
    )


def final_outputs():
    """Every final artifact of the workflow on the current config."""
    return (
        object_files("ply")
        + object_files("json")
        + template_files()
        + scene_files("npz")
        + ["results/tables/dataset_stats.csv"]
        + eval_files()
        + ablation_files()
        + (["results/noise/noise.json"] if NOISE else [])
        + (["results/realism_ablation/summary.json"] if REALISM_EFFECTS else [])
        + report_files()
    )
