# The workflow's tables and path helpers: config validation, the datasets, the methods (from the
# library's registry), the results/ layout. The only place that knows where results live.
import os
import re
import sys

from snakemake.exceptions import WorkflowError

# The library lives in src/; importable here even when the package is not installed. Each job's
# script does the same through workflow_scripts/common.py.
sys.path.insert(0, os.path.join(workflow.basedir, "src"))

from sonardet import determinism
from sonardet import methods as method_registry
from sonardet.config import (
    ConfigError,
    config_warnings,
    mismatch_test_config,
    realism_effect_config,
    realism_effects,
    realism_test_config,
    validate_config,
)
from sonardet.experiments.ablation import point_method
from sonardet.survey import enabled_surveys, tile_ids
from sonardet.seeds import derive_seed
from sonardet.sim.dataset import make_splits, scene_ids, split_names


def record_process_usage(outcome):
    """Write this (the Snakemake) process's own CPU time, its finished jobs' CPU time and its wall time
    (sonardet.report.timeline.process_usage) with the run's outcome ("success" or "error") to
    results/benchmarks/snakemake_process.json (called by the Snakefile's onsuccess / onerror).
    """
    import json

    from sonardet.io.atomic import atomic_write_text
    from sonardet.report.timeline import PROCESS_FILE, process_usage

    os.makedirs("results/benchmarks", exist_ok=True)
    doc = {"outcome": outcome, "cores": workflow.cores, **process_usage()}
    atomic_write_text(
        os.path.join("results/benchmarks", PROCESS_FILE),
        json.dumps(doc, indent=1) + "\n",
    )


def lift_local_job_rate_limit():
    """Remove the scheduler's job-start rate limit in a local run (called by the Snakefile's onstart).

    Snakemake's command line caps job starts at 100 a second (--max-jobs-per-timespan 100/1s), and
    with the cap on, its scheduler wakes every second while jobs wait for cores and runs a whole
    scheduling round (the ready jobs' input files stat'ed, the selection): a fifth to a third of a core
    of the 2-core machine through a full run, though no job can start before one ends. Locally at
    most --cores jobs run at once, so the cap never binds; without it the scheduler wakes when a job
    ends. Its value cannot be unset from the command line or a profile, and a longer timespan makes
    Snakemake wait that long before it exits, so the limiter is removed here (the attribute Snakemake
    9's JobScheduler keeps it in; remote executors such as SLURM keep their cap). Prints what it did.
    """
    scheduler = getattr(workflow, "scheduler", None)
    if not workflow.local_exec or scheduler is None:
        return
    if getattr(scheduler, "job_rate_limiter", None) is None:
        return
    scheduler.job_rate_limiter = None
    print(
        "sonardet: local run: job-start rate limit lifted (the scheduler wakes when a job ends)",
        file=sys.stderr,
    )


# Fixed thread counts and instruction-set paths of the numerical libraries for every job (inherited
# from this process): the same bytes on another machine of the same kind (README, Reproducibility).
determinism.apply()


def notice(message):
    """Print a start-up message once per run: job processes parse this file again and stay quiet."""
    if workflow.is_main_process:
        print(message, file=sys.stderr)


try:
    _validated = validate_config(config, source="workflow config", warn=False)
except ConfigError as exc:
    raise WorkflowError(str(exc))
for _message in config_warnings(_validated):
    notice(f"sonardet: warning: configuration (workflow config): {_message}")
config.clear()
config.update(_validated)

CLASSES = config["classes"]
#: Every scene id: the study's pool (train + test), then the development scenes.
SCENES = scene_ids(config["scenes"]["n_scenes"] + config["split"]["n_dev"])
SPLITS = split_names(config["split"]["fractions"])
# The split is a pure function of the config, so the DAG knows the test scenes without a checkpoint;
# the split rule writes the same lists to results/splits/ for users and other tools.
SPLIT = make_splits(
    SCENES,
    config["split"]["n_test"],
    config["split"]["n_dev"],
    config["split"]["fractions"],
    config["seed"],
)


#: Priority of the scene jobs after the training scenes (the test scenes, the scene sets): one above
#: the configured simulate priority, so that with equal configured priorities a scene is made before
#: the detections and ablation points that are ready. A scene takes seconds and frees detections of
#: minutes; among jobs of equal priority Snakemake's greedy scheduler takes those with the most input
#: first (the detections on the largest sets), so the run does not end with one long detection on
#: one core (the 878d5d6 run: the realism test set simulated at minute 40.8 of 44.6).
SCENE_PRIORITY_REST = config["workflow"]["priorities"]["simulate"] + 1


def _scene_jobs():
    """The scene simulation jobs: name -> (priority, scene ids), at most `workflow.scenes_per_job`
    scenes each (consecutive ids of one priority class). The training and dev scenes (the trainings'
    inputs) go before any other job, so the longest chain of the DAG (scenes -> training ->
    inference -> evaluation -> report) starts as early as it can; the other scenes at
    SCENE_PRIORITY_REST. Several scenes per job share one Python start-up and one reading of the
    object models (about 1 s of a 4-5 s scene); a scene's outputs do not depend on its job-mates.
    """
    first = set(SPLIT["train"]) | set(SPLIT["dev"])
    rest = [s for s in SCENES if s not in first]
    first = sorted(first)
    top = max(config["workflow"]["priorities"].values()) + 100
    per_job = int(config["workflow"]["scenes_per_job"])
    out = {}
    for klass, priority, ids in (
        ("train", top, first),
        ("other", SCENE_PRIORITY_REST, rest),
    ):
        for k in range(0, len(ids), per_job):
            out[f"{klass}{k // per_job:02d}"] = (priority, ids[k : k + per_job])
    return out


def train_priority(method):
    """A training job's priority: the configured one plus a tenth of its training fraction, so the
    largest (longest) trainings start first."""
    return PRIORITY["train"] + int(METHOD[method].fraction or 0) // 10


#: Evaluation datasets: name -> scene ids, and the folder holding their scene files. The test sets
#: (synthetic, realism, hybrid) are read only by the final detection and evaluation of each method;
#: their development counterparts (dev, realism_dev) serve every choice and the ablations.
DATASETS = {"synthetic": SPLIT["test"], "dev": SPLIT["dev"]}
DATASET_DIRS = {"synthetic": "results/scenes", "dev": "results/scenes"}
if config["realism_test"]["enabled"]:
    DATASETS["realism"] = SPLIT["test"]
    DATASET_DIRS["realism"] = "results/realism/scenes"
    DATASETS["realism_dev"] = SPLIT["dev"]
    DATASET_DIRS["realism_dev"] = "results/realism/scenes"
if config["mismatch_test"]["enabled"]:
    DATASETS["mismatch"] = SPLIT["test"][: config["mismatch_test"]["n_scenes"]]
    DATASET_DIRS["mismatch"] = "results/mismatch/scenes"
    DATASETS["mismatch_dev"] = SPLIT["dev"][: config["mismatch_test"]["n_dev"]]
    DATASET_DIRS["mismatch_dev"] = "results/mismatch/scenes"
HYBRID = config["hybrid_test"]["enabled"] and os.path.exists(
    config["hybrid_test"]["soundings"]
)
if config["hybrid_test"]["enabled"] and not HYBRID:
    notice(
        f"sonardet: hybrid_test.soundings {config['hybrid_test']['soundings']} not found: the "
        "hybrid test set is left out of this run (set hybrid_test.soundings to a real soundings "
        "table, or hybrid_test.enabled: false to silence this)"
    )
if HYBRID:
    DATASETS["hybrid"] = scene_ids(config["hybrid_test"]["n_scenes"])
    DATASET_DIRS["hybrid"] = "results/hybrid/scenes"

SCENE_JOBS = _scene_jobs()

#: Methods, from the library's registry: name -> Method (family, settings, runner, training).
METHOD = {m.name: m for m in method_registry.configured(config)}
#: The methods of the main tables, and the variants paired with them (e.g. SASA with domain
#: randomisation beside plain SASA).
METHODS = [m.name for m in method_registry.main_methods(config)]
VARIANTS = {
    m.name: m.variant_of
    for m in method_registry.variants(config, group="domain_randomisation")
}
#: Extra training seeds of the largest fraction: seed variant -> main method.
SEEDS = {m.name: m.variant_of for m in method_registry.variants(config, group="seeds")}
#: The improvement ladder's extra steps (model-based variants run on the synthetic test set).
LADDER = [m.name for m in METHOD.values() if m.group == "ladder"]
TRAINED = [n for n, m in METHOD.items() if m.trained]


def _alternation(names):
    """A wildcard regex matching exactly these names (never anything when empty)."""
    return "|".join(re.escape(n) for n in names) or "(?!)"


TRAINED_RE = _alternation(TRAINED)

#: One-at-a-time realism ablation: effect -> dataset name; its scenes are the first dev scenes.
REALISM_EFFECT_KEYS = realism_effects(config)
REALISM_EFFECTS = {e: f"realism_{e}" for e in REALISM_EFFECT_KEYS}
REALISM_ABLATION_SCENES = SPLIT["dev"][: config["realism_ablation"]["n_scenes"]]
for _effect, _dataset in REALISM_EFFECTS.items():
    DATASETS[_dataset] = REALISM_ABLATION_SCENES
    DATASET_DIRS[_dataset] = f"results/realism_ablation/{_effect}/scenes"
#: Datasets of the realism ablation's summary: plain sensor, every effect, one effect at a time.
REALISM_ABLATION_DATASETS = ["dev", "realism_dev"] + list(REALISM_EFFECTS.values())


def _scene_sets():
    """The scene sets made from the synthetic scenes' seeds under another scene config, one job per
    set (rules/scenes.smk: a job's start-up is paid once per set, not per scene): dataset -> (scene
    ids, folder, config, reuse). A realism set (its sensor profile, burial) differs from the synthetic
    scenes only after the physics, so it reuses their settled layouts (results/settled/) and MuJoCo
    settles each scene id once; a mismatch set's bodies are perturbed, so it settles its own.
    """
    configs = {}
    if config["realism_test"]["enabled"]:
        configs["realism"] = configs["realism_dev"] = (
            realism_test_config(config),
            True,
        )
    if config["mismatch_test"]["enabled"]:
        configs["mismatch"] = configs["mismatch_dev"] = (
            mismatch_test_config(config),
            False,
        )
    for effect, dataset in REALISM_EFFECTS.items():
        configs[dataset] = (realism_effect_config(config, effect), True)
    keys = ("seed", "classes", "objects", "sensor", "scenes")
    return {
        name: (DATASETS[name], DATASET_DIRS[name], {k: cfg[k] for k in keys}, reuse)
        for name, (cfg, reuse) in configs.items()
    }


SCENE_SETS = _scene_sets()
#: Datasets evaluated on their own (the ablation datasets are evaluated together, in one job).
EVAL_DATASETS = [d for d in DATASETS if d not in REALISM_EFFECTS.values()]
#: The test sets (final results); the others are development sets.
TEST_DATASETS = [
    d for d in ("synthetic", "realism", "hybrid", "mismatch") if d in DATASETS
]
#: The development sets evaluated on their own (every method, with a comparison). They serve choices,
#: not the report, so the default target makes them only with `workflow.development_sets`; the target
#: `development` makes them on demand. Their detections that the report does read (the ablation
#: reference on dev, the realism ablation on dev and realism_dev) are made either way.
DEV_DATASETS = [d for d in EVAL_DATASETS if d not in TEST_DATASETS]
DEFAULT_EVAL_DATASETS = TEST_DATASETS + (
    DEV_DATASETS if config["workflow"]["development_sets"] else []
)
#: Ablation grid points by name, the method each runs, and the test scenes they run on.
ABLATION = (
    {p["name"]: p for p in config["ablation"]["points"]}
    if config["ablation"]["enabled"]
    else {}
)
ABLATION_METHOD = {name: point_method(p, config) for name, p in ABLATION.items()}
ABLATION_SCENES = SPLIT["dev"][: config["ablation"]["n_scenes"]]
#: Scheduling per rule group, from the config (workflow.priorities, workflow.mem_mb,
#: workflow.runtime_min): every rule's priority and its job's memory and wall-clock limit.
PRIORITY = config["workflow"]["priorities"]
MEM_MB = config["workflow"]["mem_mb"]
RUNTIME_MIN = config["workflow"]["runtime_min"]


wildcard_constraints:
    cls="|".join(CLASSES),
    scene=r"s\d{4}",
    dataset="|".join(DATASETS),
    method=_alternation(METHOD),
    effect="|".join(REALISM_EFFECTS) or "none",
    point=r"[A-Za-z0-9_-]+",


# ------------------------------------------------------------------------------------------------
# The results/ layout.


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
    return [dataset_scene_file(dataset, s, ext) for s in DATASETS[dataset]]


def dataset_scene_file(dataset, scene, ext):
    """One scene file of an evaluation dataset."""
    return f"{DATASET_DIRS[dataset]}/{scene}.{ext}"


def split_scene_files(name, ext):
    """Scene files of a split (train, dev, test, train_{fraction})."""
    return expand("results/scenes/{scene}.{ext}", scene=SPLIT[name], ext=ext)


def model_file(method, name="model.pt"):
    """A trained method's file: model.pt, loss.csv or train.json."""
    return f"results/models/{method}/{name}"


def detection_file(method, dataset, scene):
    """Detections of a method on one scene of a dataset."""
    return f"results/detections/{method}/{dataset}/{scene}.json"


def detection_files(method, dataset, scenes=None):
    """Detection files of a method on the scenes of a dataset (default: all of them)."""
    return [detection_file(method, dataset, s) for s in (scenes or DATASETS[dataset])]


def scene_stats_file(method, dataset, scene):
    """Statistics of a per-scene method's job on one scene (seconds per stage, counts)."""
    return f"results/stats/{method}/{dataset}/{scene}.json"


def dataset_timing_file(method, dataset):
    """Timing of a per-dataset method's job (seconds per scene, memory, device)."""
    return f"results/stats/{method}/{dataset}/inference.json"


def timing_files(method, dataset, scenes=None):
    """Where a method's time per scene comes from: its per-scene stats files, or the timing file of
    its per-dataset job."""
    if METHOD[method].runner == "per_scene":
        return [
            scene_stats_file(method, dataset, s) for s in (scenes or DATASETS[dataset])
        ]
    return [dataset_timing_file(method, dataset)]


def metrics_file(method, dataset, name="metrics.json"):
    """Evaluation of a method on a dataset: metrics.json, per_class.csv or pr_curves.npz."""
    return f"results/eval/{method}/{dataset}/{name}"


def methods_on(dataset):
    """The configured methods run and evaluated on a dataset."""
    return [m for m in METHOD if METHOD[m].runs_on(dataset)]


#: Per-scene methods that run together on a dataset (sonardet.methods.shared_runs): dataset -> groups
#: of two or more method names; every other per-scene method has a job of its own.
SHARED_RUNS = {
    d: [
        [m.name for m in g]
        for g in method_registry.shared_runs([METHOD[n] for n in methods_on(d)])
        if len(g) > 1
    ]
    for d in DATASETS
}


def alone_re(dataset, runner):
    """Wildcard regex of the methods of a runner that run alone on `dataset` (not in SHARED_RUNS or
    SHARED_DATASET_RUNS)."""
    groups = SHARED_RUNS if runner == "per_scene" else SHARED_DATASET_RUNS
    shared = {n for g in groups.get(dataset, []) for n in g}
    return _alternation(
        n for n, m in METHOD.items() if m.runner == runner and n not in shared
    )


def eval_files(datasets, methods=None):
    """metrics.json of every method (default: all configured) on each of the evaluation datasets it
    runs on, and the comparison (bootstrap intervals, scorings) of each of those datasets.
    """
    return [
        metrics_file(m, d)
        for m in (methods or METHOD)
        for d in datasets
        if METHOD[m].runs_on(d)
    ] + [f"results/eval/compare/{d}.json" for d in datasets]


def dataset_detect_inputs(dataset):
    """Input function of a dataset's detection job: every scene of the dataset and the method's
    resources (both detection rules, per-scene and per-dataset methods, use it)."""
    return lambda w: detect_inputs(dataset, [w.method])


def detect_inputs(dataset, names):
    """Inputs of a detection job of the methods `names` on a dataset: its scenes and the methods'
    resources; with several trained methods each one's model file is `model_{method}`.
    """
    out = {"scenes": dataset_scene_files(dataset, "npz")}
    for n in names:
        out.update(method_resources(n))
    trained = [n for n in names if "model" in METHOD[n].resources]
    if len(trained) > 1:
        del out["model"]
        out.update({f"model_{n}": model_file(n) for n in trained})
    return out


def method_resources(method):
    """Named inputs a method runs with: object models, template scans, its trained model."""
    kinds = METHOD[method].resources if method in METHOD else ()
    out = {}
    if "objects" in kinds:
        out["meshes"] = object_files("ply")
        out["meta"] = object_files("json")
    if "templates" in kinds:
        out["templates"] = template_files()
    if "model" in kinds:
        out["model"] = model_file(method)
    return out


def ablation_point_inputs(wildcards):
    """Scenes, objects and templates of a grid point; a trained method also needs its training scenes."""
    method = ABLATION_METHOD[wildcards.point]
    inputs = {
        "scenes": expand("results/scenes/{scene}.npz", scene=ABLATION_SCENES),
        "labels": expand("results/scenes/{scene}.json", scene=ABLATION_SCENES),
        "meta": object_files("json"),
        "meshes": object_files("ply"),
        "templates": template_files(),
    }
    if method.trained:
        inputs["train"] = split_scene_files(f"train_{method.fraction}", "npz")
        inputs["train_labels"] = split_scene_files(f"train_{method.fraction}", "json")
    return inputs


def ablation_files():
    """Result file of every ablation grid point and of the default-settings reference."""
    if not ABLATION:
        return []
    return expand("results/ablation/points/{point}.json", point=ABLATION) + [
        "results/ablation/reference.json"
    ]


NOISE = config["noise"]["enabled"] and os.path.exists(config["noise"]["survey"])
if config["noise"]["enabled"] and not NOISE:
    notice(
        f"sonardet: noise.survey {config['noise']['survey']} not found: the noise "
        "characterisation is left out of this run (set noise.survey to a real survey file, "
        "or noise.enabled: false to silence this)"
    )


#: Report tables and figures written by the report rule; captions in config/report/ (table_*.rst, figure_*.rst).
REPORT_TABLES = (
    [
        "dataset",
        "comparison",
        "differences",
        "ladder",
        "dont_care",
        "fractions",
        "timing",
    ]
    + (["comparison_realism"] if "realism" in DATASETS else [])
    + (["ablation"] if ABLATION else [])
    + (["noise"] if NOISE else [])
    + (["comparison_hybrid"] if "hybrid" in DATASETS else [])
    + (["comparison_mismatch", "mismatch_breakdown"] if "mismatch" in DATASETS else [])
    + (["realism_ablation"] if REALISM_EFFECTS else [])
    + (["domain_randomisation"] if VARIANTS else [])
    + (["seeds"] if SEEDS else [])
)
REPORT_FIGURES = (
    ["topview", "poses3d", "pr_curves", "dataset_example"]
    + (["loss_curves"] if [m for m in TRAINED if m in METHODS] else [])
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
        + eval_files(DEFAULT_EVAL_DATASETS)
        + ablation_files()
        + (["results/noise/noise.json"] if NOISE else [])
        + (["results/realism_ablation/summary.json"] if REALISM_EFFECTS else [])
        + report_files()
    )


# ------------------------------------------------------------------------------------------------
# Rule inputs and parameters.


def train_inputs(method):
    """A trained method's training-fraction scenes and the dev scenes (its checkpoint choice)."""
    fraction = METHOD[method].fraction
    return {
        "train": split_scene_files(f"train_{fraction}", "npz"),
        "train_labels": split_scene_files(f"train_{fraction}", "json"),
        "val": split_scene_files("dev", "npz"),
        "val_labels": split_scene_files("dev", "json"),
    }


def ablation_reference_methods():
    """Per main method: its Method, detections on the ablation scenes, where its time per scene comes
    from, and (trained methods) its training summary."""
    return [
        {
            "method": METHOD[m].to_dict(),
            "detections": detection_files(m, "dev", ABLATION_SCENES),
            "timing": timing_files(m, "dev", ABLATION_SCENES),
            "train": model_file(m, "train.json") if METHOD[m].trained else None,
        }
        for m in METHODS
    ]


def realism_ablation_effects():
    """effect -> its dataset, scene JSONs, the methods' detections and the effect's config keys
    ('none': the plain scenes, 'all': the realism test set); empty without the ablation.
    """
    if not REALISM_EFFECTS:
        return {}
    sets = {"none": "dev", "all": "realism_dev", **REALISM_EFFECTS}
    methods = config["realism_ablation"]["methods"]
    return {
        effect: {
            "dataset": d,
            "scenes": [
                dataset_scene_file(d, s, "json") for s in REALISM_ABLATION_SCENES
            ],
            "detections": {
                m: detection_files(m, d, REALISM_ABLATION_SCENES) for m in methods
            },
            "keys": REALISM_EFFECT_KEYS.get(effect, []),
        }
        for effect, d in sets.items()
    }


def default_methods_on(dataset):
    """The methods whose detections on `dataset` the default target reads: every method on the sets
    it evaluates; on a development set not evaluated by default, those the ablation reference
    (`ablation_reference_methods`, on dev) and the realism ablation (`realism_ablation_effects`)
    read there."""
    if dataset in DEFAULT_EVAL_DATASETS:
        return methods_on(dataset)
    needed = (
        {e["method"]["name"] for e in ablation_reference_methods()}
        if ABLATION and dataset == "dev"
        else set()
    )
    for effect in realism_ablation_effects().values():
        if effect["dataset"] == dataset:
            needed |= set(effect["detections"])
    return [m for m in methods_on(dataset) if m in needed]


#: Per-dataset methods that run together on a dataset (sonardet.methods.shared_runs, runner
#: per_dataset: e.g. every SASA model, each scene read and prepared once): dataset -> groups of two or
#: more method names, among the methods the default target reads there (a shared job runs all of its
#: group, so a method no target asks for would be made for nothing); every other per-dataset method
#: (e.g. on the development sets for the `development` target) has a job of its own.
SHARED_DATASET_RUNS = {
    d: [
        [m.name for m in g]
        for g in method_registry.shared_runs(
            [METHOD[n] for n in default_methods_on(d)], runner="per_dataset"
        )
        if len(g) > 1
    ]
    for d in DATASETS
}


def _caption(name):
    """The caption text of a report table (config/report/table_{name}.rst), if there is one."""
    path = os.path.join(workflow.basedir, "config", "report", f"table_{name}.rst")
    return open(path).read().strip() if os.path.exists(path) else None


def report_manifest():
    """Every result file the report reads, keyed by what it is (sonardet.report.build)."""
    main = [METHOD[m] for m in METHODS]
    figure_sets = ["synthetic"] + (["hybrid"] if "hybrid" in DATASETS else [])
    return {
        "classes": CLASSES,
        "methods": [
            {
                "name": m.name,
                "family": m.family,
                "trained": m.trained,
                "fraction": m.fraction,
                "runner": m.runner,
                "training": method_registry.family(m.family).training_label(m),
            }
            for m in main
        ],
        "variants": VARIANTS,
        "seeds": SEEDS,
        "datasets": TEST_DATASETS,
        "metrics": {
            m: {d: metrics_file(m, d) for d in TEST_DATASETS if METHOD[m].runs_on(d)}
            for m in METHOD
        },
        "compare": {d: f"results/eval/compare/{d}.json" for d in TEST_DATASETS},
        "ladder": [
            {
                "name": m,
                "step": METHOD[m].settings["step"],
                "timing": timing_files(m, "synthetic"),
            }
            for m in LADDER
        ],
        "pr": {m: metrics_file(m, "synthetic", "pr_curves.npz") for m in METHODS},
        "detections": {
            d: {m: {s: detection_file(m, d, s) for s in DATASETS[d]} for m in METHODS}
            for d in figure_sets
        },
        "timing": {m: timing_files(m, "synthetic") for m in METHODS},
        "train": {
            m.name: {
                "summary": model_file(m.name, "train.json"),
                "loss": model_file(m.name, "loss.csv"),
            }
            for m in main
            if m.trained
        },
        "dataset_table": "results/tables/dataset_stats.csv",
        "scenes": {s: f"results/scenes/{s}.json" for s in SCENES},
        "scene_dir": "results/scenes",
        "scene_benchmarks": {
            f"results/benchmarks/simulate_scene/{job}.tsv": len(ids)
            for job, (_, ids) in SCENE_JOBS.items()
        },
        "test_scenes": DATASETS["synthetic"],
        "train_scenes": SPLIT["train"],
        "objects": {c: f"results/objects/{c}.json" for c in CLASSES},
        "meshes": object_files("ply"),
        "ablation": (
            {
                "points": expand(
                    "results/ablation/points/{point}.json", point=ABLATION
                ),
                "reference": "results/ablation/reference.json",
            }
            if ABLATION
            else None
        ),
        "noise": "results/noise/noise.json" if NOISE else None,
        "realism_ablation": (
            "results/realism_ablation/summary.json" if REALISM_EFFECTS else None
        ),
        "hybrid": (
            {
                s: [dataset_scene_file("hybrid", s, e) for e in ("npz", "json")]
                for s in DATASETS["hybrid"]
            }
            if "hybrid" in DATASETS
            else None
        ),
        "tables": REPORT_TABLES,
        "figures": REPORT_FIGURES,
        "figure_methods": config["report"]["figure_methods"],
        "captions": {t: _caption(t) for t in REPORT_TABLES},
        "config_info": {
            "seed": config["seed"],
            "scenes": config["scenes"]["n_scenes"],
            "sasa preset": config["sasa"]["preset"],
        },
    }


def _manifest_files(value):
    """Every file in a manifest value (strings under results/ with a suffix; not the folders)."""
    if isinstance(value, str):
        return (
            [value]
            if value.startswith("results/") and os.path.splitext(value)[1]
            else []
        )
    if isinstance(value, dict):
        return [f for v in value.values() for f in _manifest_files(v)]
    if isinstance(value, (list, tuple)):
        return [f for v in value for f in _manifest_files(v)]
    return []


# Surveys (rules/survey.smk).
#: Surveys to run: name -> settings (schema defaults filled in); missing files are reported here.
SURVEYS, _survey_messages = enabled_surveys(config["surveys"])
for _message in _survey_messages:
    notice(_message)
#: The method each survey runs (any registered method; its settings from its config section).
SURVEY_METHOD = {
    s: method_registry.get(v["method"], config) for s, v in SURVEYS.items()
}


#: Final outputs of every survey (rules/survey.smk, rule survey_detections).
SURVEY_OUTPUTS = expand(
    "results/surveys/{survey}/{name}",
    survey=SURVEYS,
    name=[
        "detections.json",
        "detections.csv",
        "detections.csv.json",
        "detections.geojson",
        "detections_crs.geojson",
        "soundings.laz",
        "objects.ply",
    ],
)


def survey_tile_inputs(wildcards):
    """One tile's points and the survey method's resources."""
    method = SURVEY_METHOD[wildcards.survey]
    out = {"npz": f"results/surveys/{wildcards.survey}/tiles/{wildcards.tile}.npz"}
    if "objects" in method.resources:
        out.update(meshes=object_files("ply"), meta=object_files("json"))
    if "templates" in method.resources:
        out["templates"] = template_files()
    if "model" in method.resources:
        out["model"] = model_file(method.name)
    return out
