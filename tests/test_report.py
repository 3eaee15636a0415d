"""Tests of sonardet.report: tables (values, study rows, CSV/Markdown/LaTeX files), figures (each writes
an informative PNG), the Pareto front on a hand example, mesh placement and the results README.

All inputs are tiny fixtures built in a temporary folder in the real formats: scene and detection
JSONs through sonardet.io.annotations, metrics and PR curves by running sonardet.eval.evaluate_files.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import trimesh

from sonardet import SCHEMA_VERSION
from sonardet.eval import evaluate_files, threshold_key
from sonardet.geometry import quat_from_yaw
from sonardet.io.annotations import write_detections, write_scene
from sonardet.objects import ObjectInfo
from sonardet.report import (
    STUDY,
    comparison_table,
    dataset_table,
    densest_region,
    fraction_table,
    image_is_informative,
    latex_table,
    machine_info,
    markdown_table,
    pareto_front,
    place_mesh,
    plot_3d_poses,
    plot_dataset_example,
    plot_loss_curves,
    plot_noise,
    plot_pareto,
    plot_pr_curves,
    plot_topview,
    timing_table,
    write_results_readme,
    write_table,
)

CLASSES = ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]
THS = [0.5, 1.0, 2.0, 4.0]
SEABED_Z = -11.0

# (cls, x, y, yaw): four objects, three of them clustered.
OBJECTS = [("reef_ring", 5.0, 5.0, 0.0), ("reef_cone", 7.0, 6.0, 0.0), ("tetrapod_b", 6.0, 8.0, 0.4),
           ("tetrapod_s", 16.0, 16.0, -0.3)]
SIZES = {"reef_ring": (2.0, 2.0, 0.75), "reef_cone": (1.8, 1.8, 1.5), "tetrapod_b": (1.6, 1.4, 1.2),
         "tetrapod_s": (1.2, 1.0, 0.9)}


def _box(cls, x, y, yaw):
    l, w, h = SIZES[cls]
    return [x, y, SEABED_Z + 0.5 * h, l, w, h, yaw]


def _scene_doc(sid, shift=0.0):
    objs = []
    for i, (cls, x, y, yaw) in enumerate(OBJECTS):
        objs.append({"id": i, "cls": cls, "pose": {"t": [x + shift, y, SEABED_Z], "q": quat_from_yaw(yaw).tolist()},
                     "box": _box(cls, x + shift, y, yaw), "n_points": 20, "visible": True})
    return {"scene": sid, "seed": 1, "config_hash": "abc123", "extent": [0.0, 20.0, 0.0, 20.0],
            "survey": {"direction": "x", "n_lines": 2, "n_pings": 20},
            "timings_s": {"seabed_s": 0.1, "physics_s": 2.0 + shift, "scan_s": 0.5}, "objects": objs}


def _scene_points(seed=0):
    """About 600 soundings: a 20 x 20 m seabed of two survey lines plus points on the four objects."""
    rng = np.random.default_rng(seed)
    gx, gy = np.meshgrid(np.linspace(0.2, 19.8, 20), np.linspace(0.2, 19.8, 20))
    sea = np.column_stack([gx.ravel(), gy.ravel(), SEABED_Z + 0.05 * rng.standard_normal(gx.size)])
    line = (sea[:, 1] >= 10.0).astype(np.int16)
    ping = np.where(line == 0, np.round(sea[:, 0]), 40 - np.round(sea[:, 0])).astype(np.int32)
    parts, labels = [sea], [np.full(len(sea), -1)]
    for i, (cls, x, y, _) in enumerate(OBJECTS):
        l, w, h = SIZES[cls]
        p = rng.uniform(-0.5, 0.5, (50, 3)) * [l, w, h] + [x, y, SEABED_Z + 0.5 * h]
        parts.append(p)
        labels.append(np.full(50, i))
    xyz = np.vstack(parts)
    n_obj = len(xyz) - len(sea)
    return {"xyz": xyz.astype(np.float64), "label": np.concatenate(labels).astype(np.int32),
            "line": np.concatenate([line, np.zeros(n_obj, np.int16)]),
            "ping": np.concatenate([ping, np.full(n_obj, 5, np.int32)]),
            "beam": np.zeros(len(xyz), np.int16)}


def _detections(with_pose: bool, shift=0.0):
    dets = []
    for k, (cls, x, y, yaw) in enumerate(OBJECTS[:3]):  # the last object is missed
        b = _box(cls, x + shift + 0.1, y, yaw)
        d = {"cls": cls, "box": b, "score": 0.9 - 0.1 * k}
        if with_pose:
            d["pose"] = {"t": [b[0], b[1], SEABED_Z], "q": quat_from_yaw(yaw).tolist()}
        dets.append(d)
    dets.append({"cls": "reef_cone", "box": _box("reef_cone", 12.0 + shift, 3.0, 0.0), "score": 0.3})  # a FP
    return dets


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A tiny result tree: 2 scenes, detections and metrics of two methods, SASA training outputs,
    model-based stats, benchmark files and a dataset statistics table."""
    root = tmp_path_factory.mktemp("results")
    scenes = {}
    for k, sid in enumerate(["s0000", "s0001"]):
        js = root / "scenes" / f"{sid}.json"
        write_scene(js, _scene_doc(sid, shift=0.0), CLASSES)
        npz = root / "scenes" / f"{sid}.npz"
        np.savez(npz, **_scene_points(k))
        scenes[sid] = (js, npz)
    out = {"root": root, "scenes": scenes, "metrics": {}, "pr": {}, "dets": {}}
    for method, pose in (("model_based_paper", True), ("sasa_100", False)):
        paths = []
        for sid in scenes:
            p = root / "detections" / method / "synthetic" / f"{sid}.json"
            write_detections(p, sid, method, _detections(pose), CLASSES)
            paths.append(p)
        out["dets"][method] = paths
        ev = root / "eval" / method / "synthetic"
        evaluate_files([scenes[s][0] for s in scenes], paths, ev / "metrics.json", ev / "per_class.csv",
                       ev / "pr_curves.npz", CLASSES, THS, 0.5, symmetric_classes=["reef_ring", "reef_cone"],
                       dataset="synthetic")
        out["metrics"][method] = ev / "metrics.json"
        out["pr"][method] = ev / "pr_curves.npz"
    for f, sids in ((50, ["s0000"]), (100, ["s0000", "s0001"])):
        d = root / "models" / f"sasa_{f}"
        d.mkdir(parents=True)
        (d / "train.json").write_text(json.dumps({
            "schema_version": SCHEMA_VERSION, "method": "sasa", "n_train_scenes": len(sids), "train_scenes": sids,
            "steps": 10 * len(sids), "train_time_s": 30.0 * len(sids), "s_per_step": 3.0, "peak_rss_mb": 900.0}))
        rows = [{"epoch": e, "loss": 5.0 / e, "loss_cls": 2.0 / e, "lr": 1e-3, "epoch_s": 3.0} for e in (1, 2, 3)]
        df = pd.DataFrame(rows)
        df["val_mAP"] = [np.nan, 0.3, 0.5 if f == 100 else 0.4]
        df.to_csv(d / "loss.csv", index=False)
    stats = []
    for k, sid in enumerate(scenes):
        p = root / "stats" / "model_based_paper" / "synthetic" / f"{sid}.json"
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps({"scene": sid, "windows": 10, "seconds": {
            "ground": 0.1 + k, "proposals": 0.2, "registration": 2.0 + k, "scoring": 0.0, "selection": 0.1,
            "total": 2.4 + 2 * k}}))
        stats.append(p)
    out["stats"] = stats
    inf = root / "stats" / "sasa_100" / "synthetic" / "inference.json"
    inf.parent.mkdir(parents=True)
    inf.write_text(json.dumps({"method": "sasa_100", "n_scenes": 2, "s_per_scene": 1.5, "device": "cpu",
                               "peak_rss_mb": 700.0}))
    out["inference"] = inf
    bench = []
    for k, sid in enumerate(scenes):
        p = root / "benchmarks" / "simulate_scene" / f"{sid}.tsv"
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text("s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
                     f"{4.0 + 2 * k:.2f}\t0:00:04\t{300.0 + 100 * k:.2f}\t700\t200\t250\t0\t9\t80\t3.8\n")
        bench.append(p)
    out["sim_bench"] = bench
    stats_csv = root / "tables" / "dataset_stats.csv"
    stats_csv.parent.mkdir(parents=True)
    stats_csv.write_text(
        "split,scenes,objects,objects_not_visible,reef_ring,reef_ring_share_pct,reef_cone,reef_cone_share_pct,"
        "tetrapod_b,tetrapod_b_share_pct,tetrapod_s,tetrapod_s_share_pct\n"
        "train,1,4,0,1,25.0,1,25.0,1,25.0,1,25.0\ntest,1,4,0,1,25.0,1,25.0,1,25.0,1,25.0\n"
        "all,2,8,0,2,25.0,2,25.0,2,25.0,2,25.0\n")
    out["dataset_stats"] = stats_csv
    return out


def _objects():
    """Stand-in meshes of the four classes in the canonical frame (base centre at the origin, z up)."""
    meshes = {
        "reef_ring": trimesh.creation.annulus(r_min=0.8, r_max=1.0, height=0.75),
        "reef_cone": trimesh.creation.cone(radius=0.9, height=1.5),
        "tetrapod_b": trimesh.creation.icosphere(subdivisions=3, radius=0.6),  # 1280 faces: decimated
        "tetrapod_s": trimesh.creation.box(extents=(1.2, 1.0, 0.9)),
    }
    out = {}
    for cls, m in meshes.items():
        m.apply_translation([0.0, 0.0, -m.bounds[0, 2]])
        out[cls] = ObjectInfo(cls=cls, mesh=m, convex_parts=[], mass_kg=1.0, volume_m3=1.0,
                              symmetry_order=0, extents_m=np.asarray(m.extents), up_axes=np.array([[0.0, 0.0, 1.0]]),
                              tumble={"mode": "stable_poses"})
    return out


# ---------------------------------------------------------------------------------------------------
# Tables


def test_comparison_table_matches_metrics_and_has_labelled_study_rows(run):
    df = comparison_table(run["metrics"], CLASSES)
    ours = df[df["source"] == "this run"].set_index("method")
    assert list(ours.index) == ["model_based_paper", "sasa_100"]
    for method, path in run["metrics"].items():
        m = json.loads(path.read_text())
        assert ours.loc[method, "mAP@0.5m"] == pytest.approx(m["mAP_headline"])
        assert ours.loc[method, "predictions"] == sum(v["n_pred"] for v in m["per_class"].values()) == 8
        assert ours.loc[method, "ground truth"] == 8
        for c in CLASSES:
            assert ours.loc[method, f"AP@0.5m {c}"] == pytest.approx(m["per_class"][c]["AP"]["0.5"])
        for t in THS[1:]:
            assert ours.loc[method, f"mAP@{threshold_key(t)}m"] == pytest.approx(m["mAP"][threshold_key(t)])
    # The tetrapod_s object is never detected: its AP is 0, the others' positive.
    assert ours.loc["sasa_100", "AP@0.5m tetrapod_s"] == 0.0
    assert ours.loc["sasa_100", "AP@0.5m reef_ring"] > 0.5
    study = df[df["source"] == "source study"].set_index("method")
    assert list(study.index) == ["SASA (study)", "model-based (study)"]
    assert study.loc["SASA (study)", "mAP@0.5m"] == 0.98 and study.loc["SASA (study)", "predictions"] == 991
    assert study.loc["model-based (study)", "mAP@0.5m"] == 0.97
    assert study.loc["model-based (study)", "predictions"] == 957
    # The study's per-class APs (ring, cone, tetrapod_b, tetrapod_s), as published.
    assert study.loc["SASA (study)", [f"AP@0.5m {c}" for c in CLASSES]].tolist() == [0.98, 0.99, 0.98, 0.96]
    assert study.loc["model-based (study)", [f"AP@0.5m {c}" for c in CLASSES]].tolist() == [0.98, 0.98, 0.97, 0.97]
    assert "SASA (study)" not in comparison_table(run["metrics"], CLASSES, study=False)["method"].tolist()


def _fraction_rows(run, summaries, annotations=None):
    """fraction_table's method rows: the SASA summaries given, then model_based_paper (no training)."""
    rows = [{"name": f"sasa_{f}", "family": "sasa", "trained": True, "fraction": f,
             "training": f"SASA, {f} % of the training split", "summary": s,
             **({"annotations": annotations[f]} if annotations and f in annotations else {})}
            for f, s in summaries.items()]
    return rows + [{"name": "model_based_paper", "family": "model_based", "trained": False, "fraction": None,
                    "training": "no training"}]


def test_fraction_table_rows_and_counts(run):
    summaries = {f: run["root"] / "models" / f"sasa_{f}" / "train.json" for f in (100, 50)}
    df = fraction_table(_fraction_rows(run, summaries), run["metrics"],
                        scenes_dir=run["root"] / "scenes").set_index("method")
    assert list(df.index) == ["sasa_50", "sasa_100", "model_based_paper"]  # fractions ascending, then no training
    assert df.loc["sasa_50", "training scenes"] == 1 and df.loc["sasa_100", "training scenes"] == 2
    assert df.loc["sasa_50", "training annotations"] == 4 and df.loc["sasa_100", "training annotations"] == 8
    assert np.isnan(df.loc["sasa_50", "mAP@0.5m"])  # sasa_50 not evaluated in this fixture
    m100 = json.loads(run["metrics"]["sasa_100"].read_text())["mAP_headline"]
    assert df.loc["sasa_100", "mAP@0.5m"] == pytest.approx(m100)
    assert df.loc["model_based_paper", "training"] == "no training"
    assert df.loc["model_based_paper", "training scenes"] == 0
    assert df.loc["sasa_100", "mAP@0.5m (study)"] == 0.98 and df.loc["sasa_50", "mAP@0.5m (study)"] == 0.97
    assert df.loc["model_based_paper", "mAP@0.5m (study)"] == STUDY["model_based_mAP"]
    # Counts given directly take precedence over counting scene files.
    df2 = fraction_table(_fraction_rows(run, {25: {"n_train_scenes": 20}}, {25: 1100}), run["metrics"])
    assert df2.iloc[0]["training annotations"] == 1100 and df2.iloc[0]["mAP@0.5m (study)"] == 0.96


def test_timing_table_stages_and_memory(run):
    df = timing_table(
        per_scene_stats={"model_based_paper": run["stats"]},
        per_dataset_timing={"sasa_100": run["inference"]},
        train_summaries={"sasa_100": run["root"] / "models" / "sasa_100" / "train.json"},
        simulation_benchmarks=run["sim_bench"],
        scene_jsons=[run["scenes"][s][0] for s in run["scenes"]],
        benchmarks={"model_based_paper": run["sim_bench"]},
    )
    assert list(df.columns) == ["method", "stage", "unit", "n", "mean", "max", "peak memory (MB)"]
    mb = df[df["method"] == "model_based_paper"].set_index("stage")
    assert list(mb.index) == ["ground", "proposals", "registration", "scoring", "selection", "total"]
    assert mb.loc["total", "mean"] == pytest.approx(3.4) and mb.loc["total", "max"] == pytest.approx(4.4)
    assert mb.loc["registration", "n"] == 2
    assert mb.loc["total", "peak memory (MB)"] == pytest.approx(400.0)
    sasa = df[df["method"] == "sasa_100"].set_index("stage")
    assert sasa.loc["inference", "mean"] == 1.5 and sasa.loc["inference", "peak memory (MB)"] == 700.0
    assert sasa.loc["training", "mean"] == 60.0 and sasa.loc["training step", "unit"] == "s/step"
    sim = df[df["method"] == "simulation"].set_index("stage")
    assert sim.loc["scene (benchmark)", "mean"] == pytest.approx(5.0)
    assert sim.loc["scene (benchmark)", "max"] == pytest.approx(6.0)
    assert sim.loc["scene (benchmark)", "peak memory (MB)"] == pytest.approx(400.0)
    assert sim.loc["physics", "mean"] == pytest.approx(2.0)
    # Jobs of several scenes: a job's seconds are shared by its scenes (4 s for 1 scene, 6 s for 3).
    a, b = run["sim_bench"]
    chunked = timing_table(simulation_benchmarks={a: 1, b: 3}).set_index("stage")
    assert chunked.loc["scene (benchmark)", "n"] == 4
    assert chunked.loc["scene (benchmark)", "mean"] == pytest.approx(10.0 / 4)
    assert chunked.loc["scene (benchmark)", "max"] == pytest.approx(4.0)
    # Already-loaded dicts work as well as paths.
    d = timing_table(per_scene_stats={"m": [json.loads(p.read_text()) for p in run["stats"]]})
    assert d.set_index("stage").loc["total", "mean"] == pytest.approx(3.4)
    assert len(timing_table()) == 0


def test_dataset_table_with_study_figures(run):
    df = dataset_table(run["dataset_stats"]).set_index("split")
    assert df.loc["train", "scenes"] == 1 and df.loc["all", "objects"] == 8
    assert df.loc["all", "reef_ring"] == "2 (25.0 %)"
    assert df.loc["train", "scenes (study)"] == 80 and df.loc["test", "scenes (study)"] == 20
    assert df.loc["all", "objects (study)"] == 5491 and df.loc["train", "objects (study)"] == 4518


def test_write_table_csv_markdown_latex(run, tmp_path):
    df = comparison_table(run["metrics"], CLASSES)
    paths = write_table(df, tmp_path / "tables" / "comparison", caption="Detection on synthetic scenes, 20 % test")
    assert [p.name for p in paths] == ["comparison.csv", "comparison.md", "comparison.tex"]
    back = pd.read_csv(paths[0])
    assert back.shape == df.shape
    assert back["mAP@0.5m"].tolist() == pytest.approx(df["mAP@0.5m"].tolist())
    md = paths[1].read_text()
    assert md.splitlines()[2].startswith("| method | source | mAP@0.5m |")
    assert "| SASA (study) | source study | 0.980 |  |  | 991 |" in md
    tex = paths[2].read_text()
    for s in ("\\toprule", "\\midrule", "\\bottomrule", "\\label{tab:comparison}", "model\\_based\\_paper",
              "20 \\% test", "SASA (study)"):
        assert s in tex
    assert tex.count("\\\\") == len(df) + 1


def test_latex_writers_agree_and_escape():
    pytest.importorskip("jinja2")
    df = pd.DataFrame({"name_a": ["x&y", "50 %"], "value": [0.12345, np.nan],
                       "n": pd.array([3, None], dtype="Int64")})
    by_pandas = latex_table(df, "cap_1", "tab:t", use_pandas=True)
    by_hand = latex_table(df, "cap_1", "tab:t", use_pandas=False)
    assert by_pandas == by_hand
    assert "x\\&y & 0.123 & 3 \\\\" in by_hand and "50 \\% & -- & -- \\\\" in by_hand
    assert latex_table(df, use_pandas=True) == latex_table(df, use_pandas=False)
    assert "\\begin{table}" not in latex_table(df, use_pandas=False)
    assert "|:---|---:|---:|" in markdown_table(df)


# ---------------------------------------------------------------------------------------------------
# Figures


def test_pareto_front_hand_example():
    df = pd.DataFrame({"s": [1.0, 2.0, 3.0, 2.0, 4.0, np.nan, 2.0], "mAP": [0.5, 0.8, 0.8, 0.7, 0.9, 1.0, 0.8]})
    # (3, .8) and (2, .7) are dominated by (2, .8); NaN never on the front; the duplicate (2, .8) is.
    assert pareto_front(df, "s", "mAP").tolist() == [True, True, False, False, True, False, True]
    assert pareto_front(df.iloc[:0], "s", "mAP").tolist() == []


def test_scene_figures_are_informative(run, tmp_path):
    js, npz = run["scenes"]["s0000"]
    dets = {m: run["dets"][m][0] for m in run["dets"]}
    top = plot_topview(npz, js, dets, tmp_path / "top.png")
    example = plot_dataset_example(npz, js, tmp_path / "example.png")
    poses = plot_3d_poses(js, dets, _objects(), tmp_path / "poses.png", scene_npz=npz)
    gt_only = plot_topview(npz, js, {}, tmp_path / "gt_only.png")
    for p in (top, example, poses, gt_only):
        assert p.is_file() and image_is_informative(p), p


def test_curve_figures_are_informative(run, tmp_path):
    pr = plot_pr_curves(run["pr"], CLASSES, tmp_path / "pr.png", threshold=0.5)
    loss = plot_loss_curves({f: run["root"] / "models" / f"sasa_{f}" / "loss.csv" for f in (50, 100)},
                            tmp_path / "loss.png")
    # Rows as sonardet.ablation writes them (name, method, mAP, seconds_per_scene, default).
    df = pd.DataFrame({"name": ["window_4", "ours_default", "sasa_default", "sasa_npoint_half"],
                       "method": ["model_based_ours", "model_based_ours", "sasa", "sasa"],
                       "seconds_per_scene": [5.0, 9.0, 1.5, 1.4], "mAP": [0.9, 0.95, 0.93, 0.8],
                       "default": [False, True, True, False]})
    pareto = plot_pareto(df, tmp_path / "pareto.png")
    rng = np.random.default_rng(0)
    d = np.concatenate([rng.normal(0.002, 0.01, 2000), rng.uniform(-0.2, 0.2, 50)])
    kept = np.abs(d - d.mean()) < 3 * d.std()
    real = {"distances_m": d, "kept_mask": kept, "mean_before": d.mean(), "sigma_before": d.std(),
            "mean_after": d[kept].mean(), "sigma_after": d[kept].std(), "name": "real survey"}
    # The simulator's result in sonardet.eval.noise's nested form (statistics under before/after).
    sim = {"distances_m": rng.normal(0, 0.012, 1000), "kept_mask": np.ones(1000, bool), "name": "simulator",
           "before": {"mean_m": 0.0, "std_m": 0.012}, "after": {"mean_m": 0.0, "std_m": 0.012}}
    noise1 = plot_noise(real, tmp_path / "noise1.png")
    noise2 = plot_noise(real, tmp_path / "noise2.png", simulated=sim)
    for p in (pr, loss, pareto, noise1, noise2):
        assert p.is_file() and image_is_informative(p), p


def test_blank_image_is_not_informative(tmp_path):
    import matplotlib.image as mpimg

    white = tmp_path / "white.png"
    mpimg.imsave(white, np.ones((40, 60, 3)))
    grey = tmp_path / "grey.png"
    mpimg.imsave(grey, np.full((40, 60, 3), 0.4))
    transparent = tmp_path / "transparent.png"
    mpimg.imsave(transparent, np.zeros((40, 60, 4)))  # black but fully transparent: white on screen
    stripes = tmp_path / "stripes.png"
    img = np.ones((40, 60, 3))
    img[::4] = 0.0
    mpimg.imsave(stripes, img)
    assert not image_is_informative(white)
    assert not image_is_informative(grey)
    assert not image_is_informative(transparent)
    assert image_is_informative(stripes)


def test_place_mesh_pose_and_box():
    v = np.array([[-1.0, -0.5, 0.0], [1.0, 0.5, 0.0], [1.0, -0.5, 2.0], [-1.0, 0.5, 2.0]])
    t, yaw = np.array([10.0, 20.0, -11.0]), 0.5 * math.pi
    posed = place_mesh(v, {"pose": {"t": t.tolist(), "q": quat_from_yaw(yaw).tolist()}, "box": [0] * 7})
    assert posed[0] == pytest.approx([10.5, 19.0, -11.0])  # (-1, -0.5) turned by 90 degrees, then moved
    # Without a pose: bounding-box centre (0, 0, 1) to the box centre, turned by the box yaw.
    boxed = place_mesh(v, {"box": [10.0, 20.0, -10.0, 1.0, 2.0, 2.0, yaw]})
    assert 0.5 * (boxed.min(0) + boxed.max(0)) == pytest.approx([10.0, 20.0, -10.0])
    assert boxed[0] == pytest.approx([10.5, 19.0, -11.0])


def test_densest_region():
    centres = [[0.0, 0.0], [30.0, 30.0], [31.0, 30.0], [30.0, 32.0], [50.0, 0.0]]
    x0, x1, y0, y1 = densest_region(centres, size_m=10.0)
    assert (x1 - x0, y1 - y0) == (10.0, 10.0)
    assert x0 <= 30.0 <= x1 and y0 <= 32.0 <= y1 and x0 <= 31.0 <= x1
    with pytest.raises(ValueError):
        densest_region([], 10.0)


# ---------------------------------------------------------------------------------------------------
# Summary


def test_results_readme_links_and_machine(run, tmp_path):
    fig = plot_pareto(pd.DataFrame({"name": ["a", "b"], "seconds_per_scene": [1.0, 2.0], "mAP": [0.5, 0.6]}),
                      tmp_path / "figures" / "pareto.png")
    info = machine_info()
    assert info["cpu_cores"] >= 1 and info["cpu_model"] and set(info["versions"]) >= {"torch", "open3d"}
    out = write_results_readme(tmp_path / "report" / "README.md",
                               {"comparison": comparison_table(run["metrics"], CLASSES)}, {"pareto": fig},
                               {"config": "config.yaml", "config_hash": "abc123"}, info)
    text = out.read_text()
    assert "## comparison" in text and "| SASA (study) |" in text
    assert "![pareto](../figures/pareto.png)" in text
    assert "abc123" in text and f"**cpu_cores**: {info['cpu_cores']}" in text
    assert f"**cpu_vector_isa**: {info['cpu_vector_isa']}" in text and "**numerical_environment**" in text


def test_the_machine_section_names_the_vector_extension_and_the_pinned_environment(monkeypatch):
    from sonardet.report.summary import vector_isa

    assert vector_isa({"sse4_2", "avx", "avx2", "fma", "avx512f"}) == "AVX-512"
    assert vector_isa({"sse4_2", "avx", "avx2", "fma"}) == "AVX2"
    assert vector_isa({"sse4_2", "avx", "avx2"}) == "AVX"  # AVX2 without FMA: not what the pin needs
    assert vector_isa(set()) == "none known"
    monkeypatch.setenv("OPENBLAS_CORETYPE", "Haswell")
    assert "OPENBLAS_CORETYPE=Haswell" in machine_info()["numerical_environment"]
    for name in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "ATEN_CPU_CAPABILITY", "MKL_CBWR",
                 "ONEDNN_MAX_CPU_ISA", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.delenv(name, raising=False)
    assert machine_info()["numerical_environment"] == "not pinned"


def test_load_metrics_rejects_foreign_files(tmp_path):
    from sonardet.report import read_metrics

    p = tmp_path / "metrics.json"
    p.write_text(json.dumps({"schema_version": SCHEMA_VERSION, "mAP_headline": 0.5}))
    with pytest.raises(ValueError, match="missing key"):
        read_metrics(p)
    p.write_text(json.dumps({"schema_version": 999}))
    with pytest.raises(ValueError, match="schema_version"):
        read_metrics(p)
