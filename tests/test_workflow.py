"""End-to-end: a real `snakemake --cores 2` run of the whole DAG on the tiny smoke config."""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import REAL_FILE, REPO, copy_workflow
from sonardet.io.templates import read_templates
from sonardet.objects import read_object

pytestmark = pytest.mark.slow


#: The smoke config's classes: the four reef elements and a fifth one from a plugin (tests/plugins).
CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s", "concrete_cube"]
#: Test sets evaluated on their own (the hybrid one needs the real line), and the development sets.
TEST_SETS = ("synthetic", "realism", "mismatch") + (("hybrid",) if REAL_FILE is not None else ())
DEV_SETS = ("dev", "realism_dev", "mismatch_dev")
EVAL_SETS = TEST_SETS + DEV_SETS


def test_objects_well_formed(smoke_run):
    for cls in CLASSES:
        meta = json.loads((smoke_run / f"results/objects/{cls}.json").read_text())
        assert meta["watertight"] and meta["cls"] == cls
        info = read_object(smoke_run / f"results/objects/{cls}.json")
        assert info.mesh.is_watertight
        assert (smoke_run / f"results/logs/object_mesh/{cls}.log").exists()
        assert (smoke_run / f"results/benchmarks/object_mesh/{cls}.tsv").exists()


def test_templates_well_formed(smoke_run):
    for cls in CLASSES:
        tv = read_templates(smoke_run / f"results/templates/{cls}.npz")
        assert tv.cls == cls and len(tv.xyz) > 100 and np.isfinite(tv.xyz).all()
        assert tv.scan_params["sensor"]["n_beams"] == 128  # from the smoke config


#: The main methods, in the registry's order; `centroid` is a toy method from a plugin (tests/plugins).
METHODS = ["model_based_paper", "model_based_ours", "sasa_25", "sasa_50", "sasa_100", "centroid"]


def _test_scenes(work):
    return (work / "results/splits/test.txt").read_text().split()


def _dev_scenes(work):
    return (work / "results/splits/dev.txt").read_text().split()


def test_scenes_and_dataset_table(smoke_run):
    ids = sorted(p.stem for p in (smoke_run / "results/scenes").glob("*.npz"))
    assert ids == ["s0000", "s0001", "s0002", "s0003", "s0004"]  # the pool of 4, then the dev scene
    assert _dev_scenes(smoke_run) == ["s0004"]
    stats = (smoke_run / "results/tables/dataset_stats.csv").read_text().splitlines()
    assert stats[0].startswith("split") and len(stats) == 5  # header + train, test, all, dev


def test_detections_of_every_method(smoke_run):
    from sonardet.io.annotations import read_detections

    test, dev = _test_scenes(smoke_run), _dev_scenes(smoke_run)
    assert len(test) == 1 and len(dev) == 1
    ablated = ["model_based_ours", "sasa_100", "sasa_dr_100"]  # realism_ablation.methods of the smoke config
    for method in METHODS + ["sasa_dr_100"]:
        sets = [(d, test) for d in ("synthetic", "realism", "mismatch")] + [(d, dev) for d in DEV_SETS]
        if method in ablated:  # the realism ablation runs on the dev scenes
            sets += [(d, dev) for d in ("realism_quantisation", "realism_burial")]
        for dataset, scenes in sets:
            for sid in scenes:
                doc = read_detections(smoke_run / f"results/detections/{method}/{dataset}/{sid}.json", CLASSES)
                assert doc["method"] == method and doc["scene"] == sid
    for variant in ("paper", "ours"):
        st = json.loads((smoke_run / f"results/stats/model_based_{variant}/synthetic/{test[0]}.json").read_text())
        assert st["variant"] == variant and st["n_points"] > 1000 and st["seconds"]["total"] > 0
    # The ladder's extra step runs on the synthetic test set only.
    assert (smoke_run / f"results/detections/model_based_paper_tight/synthetic/{test[0]}.json").exists()
    assert not (smoke_run / "results/detections/model_based_paper_tight/dev").exists()
    # ... in the job of `paper` there (they share the registrations: sonardet.methods.shared_runs).
    pair = ["model_based_paper", "model_based_paper_tight"]
    for method in pair:
        st = json.loads((smoke_run / f"results/stats/{method}/synthetic/{test[0]}.json").read_text())
        assert st["shared_run"] == pair and st["seconds"]["registration"] > 0
    assert (smoke_run / "results/benchmarks/detect_scenes/model_based_paper+model_based_paper_tight/synthetic.tsv"
            ).exists()
    assert not (smoke_run / "results/benchmarks/detect_scenes/model_based_paper/synthetic.tsv").exists()
    assert "shared_run" not in json.loads(
        (smoke_run / f"results/stats/model_based_paper/dev/{dev[0]}.json").read_text())
    # Every SASA model runs in one job per dataset (each scene read and prepared once), each with its timing file.
    sasa = ["sasa_25", "sasa_50", "sasa_100", "sasa_dr_100"]
    for method in sasa:
        t = json.loads((smoke_run / f"results/stats/{method}/synthetic/inference.json").read_text())
        assert t["method"] == method and t["shared_run"] == sasa and t["n_scenes"] == 1 and t["s_per_scene"] > 0
    assert (smoke_run / f"results/benchmarks/detect_dataset/{'+'.join(sasa)}/synthetic.tsv").exists()
    assert not (smoke_run / "results/benchmarks/detect_dataset/sasa_25/synthetic.tsv").exists()


def test_sasa_training_outputs(smoke_run):
    for f in (25, 50, 100):
        run = smoke_run / f"results/models/sasa_{f}"
        summary = json.loads((run / "train.json").read_text())
        assert summary["epochs"] == 1 and summary["steps"] >= 1 and summary["s_per_step"] > 0
        # the budget of every SASA row (issue: epochs, steps, n_points, n_parameters, device, train_s)
        for key in ("epochs", "steps", "n_points", "n_parameters", "device", "train_s"):
            assert summary[key] not in (None, ""), key
        assert summary["train_s"] == summary["train_time_s"] > 0
        rows = (run / "loss.csv").read_text().splitlines()
        assert rows[0].startswith("epoch") and len(rows) == 2
    n = [json.loads((smoke_run / f"results/models/sasa_{f}/train.json").read_text())["n_train_scenes"]
         for f in (25, 50, 100)]
    assert n[0] <= n[1] <= n[2] == 3  # nested fractions of the 3 training scenes


def test_metrics_of_every_method(smoke_run):
    for method in METHODS + ["sasa_dr_100"]:
        for dataset in EVAL_SETS:
            m = json.loads((smoke_run / f"results/eval/{method}/{dataset}/metrics.json").read_text())
            assert 0.0 <= m["mAP_headline"] <= 1.0 + 1e-9  # the devkit's normalisation rounds, as ours
            assert sum(m["per_class"][c]["n_gt"] for c in CLASSES) >= 5
    # The model-based detector needs no training: it must find the smoke scene's objects.
    ours = json.loads((smoke_run / "results/eval/model_based_ours/synthetic/metrics.json").read_text())
    assert ours["mAP_headline"] >= 0.6, ours["mAP_headline"]


def test_realism_scenes_share_the_layout(smoke_run):
    """The realism test set re-surveys the test scenes: same objects, classes and x, y; objects sunk by
    at most burial_m; other soundings."""
    sid = _test_scenes(smoke_run)[0]
    a = json.loads((smoke_run / f"results/scenes/{sid}.json").read_text())
    b = json.loads((smoke_run / f"results/realism/scenes/{sid}.json").read_text())
    assert [o["cls"] for o in a["objects"]] == [o["cls"] for o in b["objects"]]
    for oa, ob in zip(a["objects"], b["objects"]):
        assert np.allclose(oa["box"][:2], ob["box"][:2]) and 0.0 <= oa["box"][2] - ob["box"][2] <= 0.1 + 1e-9
    pa = np.load(smoke_run / f"results/scenes/{sid}.npz")["xyz"]
    pb = np.load(smoke_run / f"results/realism/scenes/{sid}.npz")["xyz"]
    assert pa.shape != pb.shape or not np.array_equal(pa, pb)
    # MuJoCo settled the scene once: the realism variant applied the synthetic scene's settled layout.
    settled = json.loads((smoke_run / f"results/settled/{sid}.json").read_text())
    assert settled["scene"] == sid and len(settled["kept"]) == len(a["objects"])
    assert b["timings_s"]["physics_reused"] == 1.0 and "physics_step_s" in a["timings_s"]
    assert "settled layout reused" in (smoke_run / "results/logs/simulate_scenes/realism.log").read_text()


def test_domain_randomised_training(smoke_run):
    plain = json.loads((smoke_run / "results/models/sasa_100/train.json").read_text())
    dr = json.loads((smoke_run / "results/models/sasa_dr_100/train.json").read_text())
    assert dr["n_train_scenes"] == plain["n_train_scenes"] and dr["steps"] == plain["steps"]
    a = (smoke_run / "results/models/sasa_100/loss.csv").read_text().splitlines()[1]
    b = (smoke_run / "results/models/sasa_dr_100/loss.csv").read_text().splitlines()[1]
    assert a != b  # the randomised training saw other points
    assert dr["params"]["dr_enabled"] is True and plain["params"]["dr_enabled"] is False


def test_realism_ablation(smoke_run):
    rows = json.loads((smoke_run / "results/realism_ablation/summary.json").read_text())
    effects = {"none", "all", "quantisation", "burial"}
    assert {(r["effect"], r["method"]) for r in rows} == {
        (e, m) for e in effects for m in ("model_based_ours", "sasa_100", "sasa_dr_100")}
    for r in rows:
        assert r["n_scenes"] == 1 and 0.0 <= r["mAP"] <= 1.0 + 1e-9
    none = {r["method"]: r for r in rows if r["effect"] == "none"}
    # "none" is the plain dev scene: its mAP is the dev evaluation's.
    main = json.loads((smoke_run / "results/eval/model_based_ours/dev/metrics.json").read_text())
    assert none["model_based_ours"]["mAP"] == pytest.approx(main["mAP_headline"], abs=1e-12)
    # The burial effect sinks objects (only it), the quantisation effect moves soundings onto a 2.9 mm grid.
    sid = _dev_scenes(smoke_run)[0]
    plain = json.loads((smoke_run / f"results/scenes/{sid}.json").read_text())
    buried = json.loads((smoke_run / f"results/realism_ablation/burial/scenes/{sid}.json").read_text())
    quant = json.loads((smoke_run / f"results/realism_ablation/quantisation/scenes/{sid}.json").read_text())
    assert any(b["box"][2] < p["box"][2] - 1e-6 for p, b in zip(plain["objects"], buried["objects"]))
    assert all(q["box"] == p["box"] for p, q in zip(plain["objects"], quant["objects"]))


@pytest.mark.skipif(REAL_FILE is None, reason="real survey data not available")
def test_hybrid_scene(smoke_run):
    from sonardet.report import image_is_informative

    meta = json.loads((smoke_run / "results/hybrid/scenes/s0000.json").read_text())
    assert meta["hybrid"]["crs"] == "EPSG:32610" and meta["hybrid"]["n_replaced"] > 1000
    assert len(meta["objects"]) >= 5 and all(o["visible"] for o in meta["objects"])
    table = pd.read_csv(smoke_run / "results/report/tables/comparison_hybrid.csv")
    assert table["method"].tolist()[: len(METHODS)] == METHODS
    assert table["source"].tolist().count("source study") == 2
    assert image_is_informative(smoke_run / "results/report/figures/hybrid_example.png")


def test_ablation_points_and_reference(smoke_run):
    names = {"paper_overlap25": "model_based_paper", "sasa50_pts512": "sasa"}
    for name, method in names.items():
        r = json.loads((smoke_run / f"results/ablation/points/{name}.json").read_text())
        assert r["method"] == method and r["n_scenes"] == 1 and r["seconds_per_scene"] > 0
        assert 0.0 <= r["mAP"] <= 1.0 + 1e-9 and r["n_gt"] >= 5
    assert json.loads((smoke_run / "results/ablation/points/sasa50_pts512.json").read_text())["train_time_s"] > 0
    ref = json.loads((smoke_run / "results/ablation/reference.json").read_text())
    assert sorted(r["name"] for r in ref) == sorted(f"{m} (default)" for m in METHODS)
    # The reference re-evaluates the main run's detections on the same dev scene: same mAP as its eval.
    main = json.loads((smoke_run / "results/eval/model_based_ours/dev/metrics.json").read_text())
    assert next(r for r in ref if r["name"] == "model_based_ours (default)")["mAP"] == pytest.approx(
        main["mAP_headline"], abs=1e-12)


def test_report_tables_and_figures(smoke_run):
    from sonardet.report import image_is_informative

    tables = smoke_run / "results/report/tables"
    expected_rows = {"dataset": 4, "comparison": len(METHODS) + 2, "comparison_realism": len(METHODS) + 2,
                     "fractions": len(METHODS), "ablation": 2 + len(METHODS), "dont_care": len(METHODS),
                     "ladder": 4,
                     # vs model_based_ours: every other method (+ sasa_dr_100) on each test set, the
                     # ladder's paper_tight on the synthetic one
                     "differences": len(METHODS) + 1 + len(METHODS) * (len(TEST_SETS) - 1)}
    expected_rows["comparison_mismatch"] = len(METHODS) + 2
    expected_rows["realism_ablation"] = 4  # none, quantisation, burial, all
    expected_rows["domain_randomisation"] = len(TEST_SETS)
    if REAL_FILE is not None:
        expected_rows["noise"] = 3  # two real patches and the simulator
        expected_rows["comparison_hybrid"] = len(METHODS) + 2
    for name, n in expected_rows.items():
        df = pd.read_csv(tables / f"{name}.csv")
        assert len(df) == n, (name, len(df))
        assert (tables / f"{name}.md").read_text().count("\n|") >= n
        assert "\\begin{tabular}" in (tables / f"{name}.tex").read_text()
    timing = pd.read_csv(tables / "timing.csv")
    assert {"model_based_paper", "model_based_ours", "sasa_100"} <= set(timing["method"])
    assert (timing["mean"] >= 0).all()
    assert (timing[timing["stage"] == "total"]["mean"] > 0).all()
    comparison = pd.read_csv(tables / "comparison.csv")
    assert comparison["source"].tolist().count("source study") == 2
    ours = comparison.set_index("method")
    for m in METHODS:  # every mAP has its bootstrap interval
        assert ours.loc[m, "map_low"] <= ours.loc[m, "mAP@0.5m"] + 1e-12 <= ours.loc[m, "map_high"] + 2e-12
    assert ours.loc["sasa_100", "n_parameters"] > 0 and ours.loc["sasa_100", "device"] == "cpu"
    figures = ["topview", "poses3d", "pr_curves", "dataset_example", "loss_curves", "pareto"]
    for name in figures:
        assert image_is_informative(smoke_run / f"results/report/figures/{name}.png"), name
    readme = (smoke_run / "results/README.md").read_text()
    assert "comparison" in readme and "figures/topview.png" in readme
    if REAL_FILE is not None:
        assert image_is_informative(smoke_run / "results/noise/noise.png")
        noise = json.loads((smoke_run / "results/noise/noise.json").read_text())
        assert 0.003 < noise["real"][0]["after"]["std_m"] < 0.015


def test_snakemake_process_usage_is_recorded(smoke_run):
    """The run records its Snakemake process's own CPU time beside its jobs' (onsuccess handler), and
    benchmarks/workflow.py reports it; the onstart handler lifts the job-start rate limit."""
    doc = json.loads((smoke_run / "results/benchmarks/snakemake_process.json").read_text())
    assert doc["outcome"] == "success" and doc["cores"] == 2
    assert doc["wall_s"] > 0 and doc["own_cpu_s"] > 0 and doc["children_cpu_s"] > doc["own_cpu_s"]
    assert 0 < doc["own_core_share"] < 2 and doc["own_max_rss_mb"] > 0
    proc = subprocess.run([sys.executable, str(REPO / "benchmarks/workflow.py"), "--results",
                           str(smoke_run / "results")], capture_output=True, text=True, check=True)
    assert "Snakemake process (success): own CPU" in proc.stdout, proc.stdout
    assert "before the jobs' own work (interpreter start, imports" in proc.stdout, proc.stdout
    assert "seconds per method" in proc.stdout and "(scenes)" in proc.stdout, proc.stdout
    # The onstart handler found Snakemake's job-start rate limiter and removed it (a local run).
    assert "job-start rate limit lifted" in (smoke_run / "snakemake_output.txt").read_text()


def test_every_job_records_its_exact_cpu(smoke_run):
    """Each job writes its CPU seconds and threads beside its log at its end, and the time line uses
    them instead of Snakemake's sampled cpu_time: every job has one, their sum is at most what the
    Snakemake process counted for its children, and the timeline summary says so."""
    from sonardet.report.timeline import read_benchmarks

    df = read_benchmarks(smoke_run / "results/benchmarks")
    df = df[df["rule"] != "run_timeline"]
    missing = df.loc[~df["cpu_exact"].astype(bool), "job"].tolist()
    assert not missing, missing
    # each job's end time comes from its record, taken just before Snakemake wrote its benchmark file
    assert (df["end_from"] == "record").all()
    mtime = {j: (smoke_run / "results/benchmarks" / f"{j}.tsv").stat().st_mtime for j in df["job"]}
    lag = df["job"].map(mtime) - df["end"]
    assert ((lag > -1.0) & (lag < 60.0)).all(), df.assign(lag=lag).loc[~((lag > -1.0) & (lag < 60.0)), ["job", "lag"]]
    assert (df["cpu_s"] > 0).all() and (df["threads"] >= 1).all()
    # the CPU before a job's own work (interpreter, imports) is part of its CPU, and a job that runs
    # no method imports no method registry: its start-up stays well under a heavy job's
    assert (df["startup_cpu_s"] > 0).all() and (df["startup_cpu_s"] <= df["cpu_s"]).all()
    startup = df.groupby("rule")["startup_cpu_s"].median()
    assert startup["evaluate"] < 0.5 * startup["simulate_scene"], startup.to_dict()
    kids = json.loads((smoke_run / "results/benchmarks/snakemake_process.json").read_text())["children_cpu_s"]
    assert df["cpu_s"].sum() <= kids * 1.01 + 1.0
    summary = json.loads((smoke_run / "results/report/timeline.json").read_text())
    assert summary["cpu_exact_jobs"] == summary["jobs"] and summary["idle_core_s"] >= 0
    assert summary["startup_jobs"] == summary["jobs"] and 0 < summary["startup_cpu_s"] < summary["cpu_s"]
    # every job records its Numba compilation time (zero in most), within its CPU
    assert summary["jit_recorded_jobs"] == summary["jobs"] and 0 <= summary["jit_s"] < summary["cpu_s"]
    # every job's time is counted for one method group, the plugin's toy method among them
    per_method = summary["per_method"]
    assert sum(v["sum_s"] for v in per_method.values()) == pytest.approx(summary["job_s"])
    assert {"(scenes)", "model_based_ours", "centroid"} <= set(per_method), sorted(per_method)


def test_toy_method_from_a_plugin(smoke_run):
    """A method defined only in tests/plugins/centroid_method.py and registered from the config is run
    per scene, evaluated on every test set and shown in the comparison and timing tables."""
    sid = _test_scenes(smoke_run)[0]
    for dataset in EVAL_SETS:
        m = json.loads((smoke_run / f"results/eval/centroid/{dataset}/metrics.json").read_text())
        assert 0.0 <= m["mAP_headline"] <= 1.0 + 1e-9
    st = json.loads((smoke_run / f"results/stats/centroid/synthetic/{sid}.json").read_text())
    assert st["scene"] == sid and st["seconds"]["total"] >= 0
    tables = smoke_run / "results/report/tables"
    assert "centroid" in pd.read_csv(tables / "comparison.csv")["method"].tolist()
    timing = pd.read_csv(tables / "timing.csv")
    assert timing[(timing["method"] == "centroid") & (timing["stage"] == "total")]["n"].tolist() == [1]
    fractions = pd.read_csv(tables / "fractions.csv").set_index("method")
    assert fractions.loc["centroid", "training"] == "no training"


def test_fifth_class_from_a_plugin(smoke_run):
    """A class defined only in tests/plugins/cube_class.py (one spec) and listed in `classes` is built,
    scanned, placed in scenes, detected by every method and evaluated."""
    meta = json.loads((smoke_run / "results/objects/concrete_cube.json").read_text())
    assert meta["symmetry_order"] == 4 and abs(meta["volume_m3"] - 1.728) < 1e-6 and len(meta["up_axes"]) == 6
    tv = read_templates(smoke_run / "results/templates/concrete_cube.npz")
    assert len(tv.xyz) > 100
    cubes = [o for p in (smoke_run / "results/scenes").glob("*.json")
             for o in json.loads(p.read_text())["objects"] if o["cls"] == "concrete_cube"]
    assert cubes and all(o["arrangement"] == "scatter" for o in cubes)
    comparison = pd.read_csv(smoke_run / "results/report/tables/comparison.csv")
    assert "AP@0.5m concrete_cube" in comparison.columns
    m = json.loads((smoke_run / "results/eval/model_based_ours/synthetic/metrics.json").read_text())
    assert "concrete_cube" in m["per_class"]
    model = json.loads((smoke_run / "results/models/sasa_100/train.json").read_text())
    assert model["params"]["symmetry_orders"]["concrete_cube"] == 4


def test_html_report(smoke_run):
    proc = subprocess.run([sys.executable, "-m", "snakemake", "--configfile", "config_smoke.yaml",
                           "--report", "results/report.html"], cwd=smoke_run, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    html = (smoke_run / "results/report.html")
    assert html.stat().st_size > 100_000  # self-contained: figures and tables embedded


def test_threshold_change_reruns_only_its_jobs(smoke_run):
    cfg = (smoke_run / "config_smoke.yaml").read_text().replace(
        "ours: {proposal_max_rounds_n: 2}", "ours: {proposal_max_rounds_n: 2, accept_min: 0.4}")
    assert "accept_min" in cfg
    (smoke_run / "config_changed.yaml").write_text(cfg)
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--configfile", "config_changed.yaml"],
                          cwd=smoke_run, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = _job_counts(proc.stdout + proc.stderr)
    # Only the changed variant's detections (test sets, dev sets, the two realism-ablation sets), their
    # evaluations and comparisons and what reads them.
    n_sets = len(EVAL_SETS)
    detect = {r: n for r, n in jobs.items() if r.startswith("detect_scenes_")}  # one job per dataset
    assert len(detect) == n_sets + 2 and set(detect.values()) == {1}, jobs
    rest = {r: n for r, n in jobs.items() if r not in detect}
    assert rest == {"evaluate": n_sets, "compare": n_sets, "ablation_reference": 1, "realism_ablation": 1,
                    "report": 1, "run_timeline": 1, "all": 1}, jobs


def _job_counts(text: str) -> dict:
    """The job-count table of a Snakemake dry run, as {rule: count} (without the total)."""
    out, inside = {}, False
    for line in text.splitlines():
        parts = line.split()
        if parts[:2] == ["job", "count"]:
            inside = True
            continue
        if inside:
            if not parts or parts[0] == "total":
                break
            if len(parts) == 2 and parts[1].isdigit():
                out[parts[0]] = int(parts[1])
    return out


def _dag_outputs(work, configfile: str, *targets: str) -> set[str]:
    """Every output file of the DAG of `targets` (the default target when none) in `work`, from
    Snakemake's `--summary` table (its first column)."""
    # the targets first: --configfile takes every word after it
    proc = subprocess.run([sys.executable, "-m", "snakemake", *targets, "--summary", "--configfile", configfile],
                          cwd=work, capture_output=True, text=True)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    rows = [line.split("\t") for line in proc.stdout.splitlines()]
    assert rows and rows[0][0] == "output_file", proc.stdout[:500]
    return {r[0] for r in rows[1:] if r[0]}


def test_default_target_leaves_out_the_development_sets(smoke_run):
    """With workflow.development_sets false (the default config's setting) the default target
    evaluates every method on the test sets only: no evaluation or comparison on dev, realism_dev or
    mismatch_dev and no mismatch_dev scenes, which the report does not read; the detections on dev and
    realism_dev that the ablation reference and the realism ablation read are still made. The target
    `development` makes the rest."""
    cfg = (smoke_run / "config_smoke.yaml").read_text().replace("development_sets: true", "development_sets: false")
    assert "development_sets: false" in cfg
    (smoke_run / "config_nodev.yaml").write_text(cfg)
    dev = _dev_scenes(smoke_run)[0]
    default = _dag_outputs(smoke_run, "config_nodev.yaml")
    assert "results/report/timeline.json" in default and "results/eval/model_based_ours/synthetic/metrics.json" in default
    for d in DEV_SETS:
        assert f"results/eval/compare/{d}.json" not in default
        assert not {p for p in default if p.startswith("results/eval/") and f"/{d}/" in p}, d
    assert f"results/mismatch/scenes/{dev}.npz" not in default
    assert f"results/detections/model_based_paper/dev/{dev}.json" in default  # the ablation reference
    assert f"results/detections/model_based_ours/realism_dev/{dev}.json" in default  # the realism ablation
    assert f"results/detections/model_based_paper/realism_dev/{dev}.json" not in default
    development = _dag_outputs(smoke_run, "config_nodev.yaml", "development")
    for d in DEV_SETS:
        assert f"results/eval/compare/{d}.json" in development
        assert f"results/eval/sasa_dr_100/{d}/metrics.json" in development
    assert f"results/mismatch/scenes/{dev}.npz" in development
    assert "results/report/timeline.json" not in development
    # with the key on (the smoke config) the default target holds them all
    assert development <= _dag_outputs(smoke_run, "config_smoke.yaml")


def test_scenes_are_the_same_in_jobs_of_any_size(smoke_run, tmp_path):
    """The smoke run made its training and dev scenes in one job and the test scene in another
    (`workflow.scenes_per_job` 5); made one job per scene in a copy of the workflow, a scene of each
    is the same: soundings byte for byte, annotations and settled layout equal but for the seconds."""
    jobs = sorted(p.stem for p in (smoke_run / "results/logs/simulate_scene").glob("*.log"))
    assert jobs == ["other00", "train00"]
    (tmp_path / "one_per_job").mkdir()
    work = copy_workflow(tmp_path / "one_per_job")
    cfg = yaml.safe_load((smoke_run / "config_smoke.yaml").read_text())
    cfg.setdefault("workflow", {})["scenes_per_job"] = 1
    (work / "config_one.yaml").write_text(yaml.safe_dump(cfg))
    scenes = [_test_scenes(smoke_run)[0], _dev_scenes(smoke_run)[0]]
    targets = [f"results/scenes/{s}.npz" for s in scenes]
    proc = subprocess.run([sys.executable, "-m", "snakemake", *targets, "--cores", "2", "--configfile",
                           "config_one.yaml"], cwd=work, capture_output=True, text=True)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    made = sorted(p.stem for p in (work / "results/logs/simulate_scene").glob("*.log"))
    assert len(made) == 2 and made[0].startswith("other") and made[1].startswith("train"), made

    def without_seconds(path):
        d = json.loads(path.read_text())
        d.pop("timings_s", None)
        return d

    for s in scenes:
        one, five = work / "results", smoke_run / "results"
        assert (one / f"scenes/{s}.npz").read_bytes() == (five / f"scenes/{s}.npz").read_bytes()
        assert without_seconds(one / f"scenes/{s}.json") == without_seconds(five / f"scenes/{s}.json")
        assert (one / f"settled/{s}.json").read_text() == (five / f"settled/{s}.json").read_text()


def test_rerun_is_a_no_op_and_deterministic(smoke_run):
    before = (smoke_run / "results/templates/tetrapod_s.npz").read_bytes()
    proc = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--configfile", "config_smoke.yaml"],
                          cwd=smoke_run, capture_output=True, text=True)
    assert proc.returncode == 0 and "Nothing to be done" in proc.stdout + proc.stderr
    tv = read_templates(smoke_run / "results/templates/tetrapod_s.npz")
    # The target before --forcerun, which takes several values: after it, the target would be read
    # as a second rule to force and the default target (every template's dependants) rerun.
    proc = subprocess.run([sys.executable, "-m", "snakemake", "results/templates/tetrapod_s.npz", "--cores", "1",
                           "--configfile", "config_smoke.yaml", "--forcerun", "template_scan"],
                          cwd=smoke_run, capture_output=True, text=True, check=True)
    assert "1 of 1 steps (100%) done" in proc.stdout + proc.stderr
    again = read_templates(smoke_run / "results/templates/tetrapod_s.npz")
    assert np.array_equal(tv.xyz, again.xyz)
    assert len(before) > 0
