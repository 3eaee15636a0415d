"""Write the report: tables (csv, md, tex), figures and results/README.md from this run's results."""

import os
import sys

sys.path.insert(0, os.path.join(snakemake.scriptdir, "..", "src"))  # noqa: F821  library without install

import json
from pathlib import Path

import pandas as pd

from sonardet import report as rp
from sonardet.workflow import rule_logging

with rule_logging(snakemake, "report") as log:  # noqa: F821
    smk = snakemake  # noqa: F821
    methods, classes = smk.params.methods, smk.params.classes
    tdir, fdir = Path(smk.output.tables_md[0]).parent, Path(smk.output.figures[0]).parent

    def of(method, paths, level=2):
        """The paths of `method` among results/{kind}/{method}/... files (method = parent `level` up)."""
        return [p for p in paths if Path(p).parents[level - 1].name == method]

    def metrics_on(dataset, which=None):
        """method -> results/eval/{method}/{dataset}/metrics.json (default: the main methods)"""
        return {m: next(p for p in smk.input.metrics if Path(p).parent.name == dataset
                        and Path(p).parents[1].name == m) for m in (methods if which is None else which)}

    # For reference only: the study measured these on real Baltic Sea sonar, not on our test sets.
    study_real = pd.DataFrame([{"method": "model-based (study, real sonar)", "source": "source study"},
                               {"method": "SASA (study, real sonar)", "source": "source study"}])

    metrics = metrics_on("synthetic")
    tables = {"dataset": rp.dataset_table(smk.input.dataset), "comparison": rp.comparison_table(metrics, classes)}
    for dataset in ("realism", "hybrid"):
        if f"comparison_{dataset}" in smk.params.tables:
            real = rp.comparison_table(metrics_on(dataset), classes, study=False)
            study = study_real.copy()
            study[real.columns[2]] = [0.83, 0.40]
            tables[f"comparison_{dataset}"] = pd.concat([real, study], ignore_index=True)
    if "realism_ablation" in smk.params.tables:
        tables["realism_ablation"] = rp.realism_ablation_table(smk.input.realism_ablation[0])
    if "domain_randomisation" in smk.params.tables:
        pairs = dict(smk.params.dr_pairs)
        tables["domain_randomisation"] = rp.domain_randomisation_table(
            {d: metrics_on(d, list(pairs) + list(pairs.values())) for d in smk.params.datasets}, pairs)
    sasa = [m for m in methods if m.startswith("sasa_")]
    train = {m: of(m, smk.input.training, 1)[0] for m in sasa}
    tables["fractions"] = rp.fraction_table(train, metrics, scenes_dir=Path(smk.input.scenes[0]).parent)
    tables["timing"] = rp.timing_table(
        model_based_stats={m: of(m, smk.input.stats) for m in methods if m.startswith("model_based_")},
        sasa_inference={m: of(m, smk.input.inference)[0] for m in sasa}, sasa_train=train,
        simulation_benchmarks=smk.input.scene_benchmarks, scene_jsons=smk.input.scenes)
    if "ablation" in smk.params.tables:
        rows = [json.loads(Path(p).read_text()) for p in smk.input.ablation if Path(p).parent.name == "points"]
        ref = json.loads(Path(next(p for p in smk.input.ablation if Path(p).name == "reference.json")).read_text())
        ab = pd.DataFrame(ref + rows)
        ab["default"] = ab.get("default", False).fillna(False).astype(bool)
        ab["params"] = ab["params"].map(lambda d: json.dumps(d, separators=(",", ":")) if d else "")
        cols = ["name", "method", "fraction", "params", "mAP", "seconds_per_scene", "seconds_per_scene_max",
                "train_time_s", "n_pred", "n_gt", "n_scenes", "default"]
        tables["ablation"] = ab[cols].sort_values(["method", "seconds_per_scene"]).reset_index(drop=True)
    if "noise" in smk.params.tables:
        doc = json.loads(Path(smk.input.noise[0]).read_text())
        rows = []
        for r, src in [(r, "real survey") for r in doc["real"]] + [(doc["simulated"], "simulator")]:
            rows.append({"patch": r["name"], "data": src, "points": r["n_points"],
                         "slope (deg)": r["plane"]["slope_deg"],
                         "sigma before (mm)": 1e3 * r["before"]["std_m"], "sigma after (mm)": 1e3 * r["after"]["std_m"],
                         "robust sigma (mm)": 1e3 * r["before"]["robust_sigma_m"],
                         "skewness p before": r["before"]["skewtest_pvalue"],
                         "skewness p after": r["after"]["skewtest_pvalue"]})
        tables["noise"] = pd.DataFrame(rows)
    for name, df in tables.items():
        rp.write_table(df, tdir / name, caption=Path(f"config/report/table_{name}.rst").read_text().strip()
                       if Path(f"config/report/table_{name}.rst").exists() else None)
        log.info("table %s: %d rows", name, len(df))

    # Figures: the test scene with the most objects shows the detectors at their busiest.
    test = smk.params.test_scenes
    scene_dir = Path(smk.input.scenes[0]).parent
    n_obj = {s: len(json.loads((scene_dir / f"{s}.json").read_text())["objects"]) for s in test}
    sid = max(test, key=lambda s: (n_obj[s], s))
    shown = [m for m in ("model_based_paper", "model_based_ours", "sasa_100") if m in methods] or methods[:3]
    dets = {m: next(p for p in smk.input.detections if Path(p).parent.parent.name == m and Path(p).stem == sid)
            for m in shown}
    figures = {}
    want = smk.params.figures
    if "topview" in want:
        figures["topview"] = rp.plot_topview(scene_dir / f"{sid}.npz", scene_dir / f"{sid}.json", dets,
                                             fdir / "topview.png")
    if "poses3d" in want:
        objects = {Path(p).stem: p for p in smk.input.meta}
        figures["poses3d"] = rp.plot_3d_poses(scene_dir / f"{sid}.json", dets, objects, fdir / "poses3d.png",
                                              scene_npz=scene_dir / f"{sid}.npz")
    if "pr_curves" in want:
        figures["pr_curves"] = rp.plot_pr_curves({m: of(m, smk.input.pr)[0] for m in methods}, classes,
                                                 fdir / "pr_curves.png")
    if "dataset_example" in want:
        ex = smk.params.train_scenes[0]
        figures["dataset_example"] = rp.plot_dataset_example(scene_dir / f"{ex}.npz", scene_dir / f"{ex}.json",
                                                             fdir / "dataset_example.png")
    if "loss_curves" in want:
        figures["loss_curves"] = rp.plot_loss_curves({m: of(m, smk.input.losses, 1)[0] for m in sasa},
                                                     fdir / "loss_curves.png")
    if "pareto" in want:
        figures["pareto"] = rp.plot_pareto(tables["ablation"], fdir / "pareto.png", default_mask="default")
    if "hybrid_example" in want:
        # The hybrid scene with the most objects, with the same methods as the synthetic top view.
        hjs = [Path(p) for p in smk.input.hybrid_scenes if p.endswith(".json")]
        hsid = max(hjs, key=lambda p: (len(json.loads(p.read_text())["objects"]), p.stem)).stem
        hdets = {m: next(p for p in smk.input.hybrid_detections if Path(p).parent.parent.name == m
                         and Path(p).stem == hsid) for m in shown}
        hdir = hjs[0].parent
        figures["hybrid_example"] = rp.plot_topview(hdir / f"{hsid}.npz", hdir / f"{hsid}.json", hdets,
                                                    fdir / "hybrid_example.png")
    if smk.input.noise:
        figures["noise"] = Path(smk.input.noise[0]).with_suffix(".png")
    for name, path in figures.items():
        if not rp.image_is_informative(path):
            raise RuntimeError(f"figure {name} ({path}) came out blank")
    rp.write_results_readme(smk.output.readme, tables, figures, dict(smk.params.config_info),
                            rp.machine_info(), title="sonardet results")
    log.info("report: %d tables, %d figures, summary %s", len(tables), len(figures), smk.output.readme)
