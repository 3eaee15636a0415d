"""The whole report from a manifest of result files: tables (csv, md, tex), figures, a summary README.

The workflow (rules/report.smk) writes the manifest; nothing here knows the results/ layout or
parses a path for a method or dataset name. Manifest keys:

* classes; methods (main methods, in order: {name, family, trained, fraction, runner, training
  (label)}); variants ({variant: base method}); datasets (evaluated on their own);
* metrics {method: {dataset: metrics.json}}; pr {method: pr_curves.npz} (synthetic);
* detections {dataset: {method: {scene: detections json}}} for the figures' datasets;
* timing {method: [stats or timing files]} (synthetic); train {method: {summary, loss}};
* dataset_table (dataset_stats.csv); scenes {scene: json}; scene_dir; scene_benchmarks {tsv: scenes in
  that job} (or [tsv], one scene each);
  test_scenes, train_scenes; objects {cls: json};
* ablation {points: [json], reference: json} or None; noise json or None; realism_ablation json or
  None; hybrid {scene: [npz, json]} or None;
* tables, figures (names to write); figure_methods; captions {table: text}; config_info.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd

from ..io.atomic import atomic_outputs
from .figures import (
    image_is_informative,
    plot_3d_poses,
    plot_dataset_example,
    plot_loss_curves,
    plot_pareto,
    plot_pr_curves,
    plot_topview,
)
from .inputs import read_json
from .study import STUDY_REAL_SONAR, STUDY_SOURCE
from .summary import machine_info, write_results_readme
from .tables import (
    TABLE_SUFFIXES,
    breakdown_table,
    comparison_table,
    dataset_table,
    differences_table,
    domain_randomisation_table,
    fraction_table,
    ladder_table,
    realism_ablation_table,
    scoring_table,
    seeds_table,
    timing_table,
    write_table,
)

__all__ = ["build_figures", "build_tables", "write_report"]


def _metrics_on(man: dict, dataset: str, methods=None) -> dict:
    return {m: man["metrics"][m][dataset] for m in (methods or [x["name"] for x in man["methods"]])}


def _with_real_sonar(table: pd.DataFrame) -> pd.DataFrame:
    """A comparison on a realism-like set with the study's real-sonar figures below, for reference."""
    study = pd.DataFrame([{"method": k, "source": STUDY_SOURCE} for k in STUDY_REAL_SONAR])
    study[table.columns[2]] = list(STUDY_REAL_SONAR.values())
    return pd.concat([table, study], ignore_index=True)


def _ablation_table(ablation: dict) -> pd.DataFrame:
    rows = [read_json(p) for p in ablation["points"]]
    ref = read_json(ablation["reference"])
    ab = pd.DataFrame(ref + rows)
    ab["default"] = ab.get("default", False).fillna(False).astype(bool)
    ab["params"] = ab["params"].map(lambda d: json.dumps(d, separators=(",", ":")) if d else "")
    cols = ["name", "method", "fraction", "params", "mAP", "seconds_per_scene", "seconds_per_scene_max",
            "train_time_s", "n_pred", "n_gt", "n_scenes", "default"]
    return ab[cols].sort_values(["method", "seconds_per_scene"]).reset_index(drop=True)


def _noise_table(noise_json) -> pd.DataFrame:
    doc = read_json(noise_json)
    rows = []
    for r, src in [(r, "real survey") for r in doc["real"]] + [(doc["simulated"], "simulator")]:
        rows.append({"patch": r["name"], "data": src, "points": r["n_points"], "slope (deg)": r["plane"]["slope_deg"],
                     "sigma before (mm)": 1e3 * r["before"]["std_m"], "sigma after (mm)": 1e3 * r["after"]["std_m"],
                     "robust sigma (mm)": 1e3 * r["before"]["robust_sigma_m"],
                     "skewness p before": r["before"]["skewtest_pvalue"],
                     "skewness p after": r["after"]["skewtest_pvalue"]})
    return pd.DataFrame(rows)


def _timing(man: dict) -> pd.DataFrame:
    per_scene = {m["name"]: man["timing"][m["name"]] for m in man["methods"] if m["runner"] == "per_scene"}
    per_dataset = {m["name"]: man["timing"][m["name"]][0] for m in man["methods"] if m["runner"] == "per_dataset"}
    train = {m["name"]: man["train"][m["name"]]["summary"] for m in man["methods"] if m["trained"]}
    return timing_table(per_scene_stats=per_scene, per_dataset_timing=per_dataset, train_summaries=train,
                        simulation_benchmarks=man["scene_benchmarks"], scene_jsons=list(man["scenes"].values()))


def _intervals(man: dict, dataset: str) -> dict:
    """method -> (low, high) bootstrap interval of its mAP on a dataset (all boxes)."""
    rows = read_json(man["compare"][dataset])["scorings"]["all"]
    return {m: (r["low"], r["high"]) for m, r in rows.items()}


def _budgets(man: dict) -> dict:
    """Trained method -> its train.json (the budget columns of the comparison tables)."""
    return {m["name"]: man["train"][m["name"]]["summary"] for m in man["methods"] if m["trained"]}


def _seconds(stats_files) -> list[float]:
    return [float(read_json(p)["seconds"]["total"]) for p in stats_files]


def _ladder(man: dict) -> pd.DataFrame:
    """paper (the study's ranking) -> each configured step -> ours, accepted objects only -> ours."""
    names = [m["name"] for m in man["methods"]]
    steps = []
    if "model_based_paper" in names:
        steps.append({"method": "model_based_paper", "step": "the study's pipeline (RMSE ranking)", "scoring": "all",
                      "seconds": _seconds(man["timing"]["model_based_paper"])})
    steps += [{"method": st["name"], "step": st["step"], "scoring": "all", "seconds": _seconds(st["timing"])}
              for st in man["ladder"]]
    if "model_based_ours" in names:
        secs = _seconds(man["timing"]["model_based_ours"])
        steps.append({"method": "model_based_ours", "step": "ours: terrain-following seabed, proposals, robust ICP, "
                      "two-way scores, explain-away (accepted objects only)", "scoring": "accepted", "seconds": secs})
        steps.append({"method": "model_based_ours", "step": "+ low-score tail of rejected hypotheses",
                      "scoring": "all", "seconds": secs})
    return ladder_table(steps, man["compare"]["synthetic"])


def build_tables(man: dict) -> dict[str, pd.DataFrame]:
    """Every table the manifest asks for (`tables`), by name."""
    want, classes = man["tables"], man["classes"]
    tables = {"dataset": dataset_table(man["dataset_table"]),
              "comparison": comparison_table(_metrics_on(man, "synthetic"), classes,
                                             intervals=_intervals(man, "synthetic"), budgets=_budgets(man))}
    for dataset in ("realism", "hybrid", "mismatch"):
        if f"comparison_{dataset}" in want:
            tables[f"comparison_{dataset}"] = _with_real_sonar(
                comparison_table(_metrics_on(man, dataset), classes, study=False,
                                 intervals=_intervals(man, dataset), budgets=_budgets(man)))
    if "mismatch_breakdown" in want:
        tables["mismatch_breakdown"] = breakdown_table(man["compare"]["mismatch"])
    tables["differences"] = differences_table({d: man["compare"][d] for d in man["datasets"]})
    tables["ladder"] = _ladder(man)
    tables["dont_care"] = scoring_table(man["compare"]["synthetic"], [m["name"] for m in man["methods"]])
    if "realism_ablation" in want:
        tables["realism_ablation"] = realism_ablation_table(man["realism_ablation"])
    if "domain_randomisation" in want:
        pairs = dict(man["variants"])
        tables["domain_randomisation"] = domain_randomisation_table(
            {d: _metrics_on(man, d, list(pairs) + list(pairs.values())) for d in man["datasets"]}, pairs)
    trained = [dict(m, summary=man["train"][m["name"]]["summary"]) if m["trained"] else m for m in man["methods"]]
    tables["fractions"] = fraction_table(trained, _metrics_on(man, "synthetic"), scenes_dir=man["scene_dir"])
    tables["timing"] = _timing(man)
    if "ablation" in want:
        tables["ablation"] = _ablation_table(man["ablation"])
    if "noise" in want:
        tables["noise"] = _noise_table(man["noise"])
    if "seeds" in want:
        groups = {}
        for variant, main in man["seeds"].items():
            groups.setdefault(main, {main: man["metrics"][main]["synthetic"]})[variant] = \
                man["metrics"][variant]["synthetic"]
        tables["seeds"] = seeds_table(groups)
    return {k: v for k, v in tables.items() if k in want}


def _busiest(scene_jsons: dict, scenes) -> str:
    """The scene with the most objects (ties: the last id): it shows the detectors at their busiest."""
    n_obj = {s: len(read_json(scene_jsons[s])["objects"]) for s in scenes}
    return max(scenes, key=lambda s: (n_obj[s], s))


def _shown(man: dict) -> list[str]:
    names = [m["name"] for m in man["methods"]]
    return [m for m in man["figure_methods"] if m in names] or names[:3]


def build_figures(man: dict, tables: dict, fdir) -> dict[str, Path]:
    """Every figure the manifest asks for (`figures`), written into fdir; name -> PNG path."""
    fdir, want, shown = Path(fdir), man["figures"], _shown(man)
    scene_dir = Path(man["scene_dir"])
    sid = _busiest(man["scenes"], man["test_scenes"])
    dets = {m: man["detections"]["synthetic"][m][sid] for m in shown}
    out = {}
    if "topview" in want:
        out["topview"] = plot_topview(scene_dir / f"{sid}.npz", scene_dir / f"{sid}.json", dets, fdir / "topview.png")
    if "poses3d" in want:
        out["poses3d"] = plot_3d_poses(scene_dir / f"{sid}.json", dets, dict(man["objects"]), fdir / "poses3d.png",
                                       scene_npz=scene_dir / f"{sid}.npz")
    if "pr_curves" in want:
        out["pr_curves"] = plot_pr_curves(dict(man["pr"]), man["classes"], fdir / "pr_curves.png")
    if "dataset_example" in want:
        ex = man["train_scenes"][0]
        out["dataset_example"] = plot_dataset_example(scene_dir / f"{ex}.npz", scene_dir / f"{ex}.json",
                                                      fdir / "dataset_example.png")
    if "loss_curves" in want:
        losses = {m["name"]: man["train"][m["name"]]["loss"] for m in man["methods"] if m["trained"]}
        out["loss_curves"] = plot_loss_curves(losses, fdir / "loss_curves.png")
    if "pareto" in want:
        out["pareto"] = plot_pareto(tables["ablation"], fdir / "pareto.png", default_mask="default")
    if "hybrid_example" in want:
        hybrid = {s: files[1] for s, files in man["hybrid"].items()}
        hsid = _busiest(hybrid, sorted(hybrid))
        npz, js = man["hybrid"][hsid]
        hdets = {m: man["detections"]["hybrid"][m][hsid] for m in shown}
        out["hybrid_example"] = plot_topview(npz, js, hdets, fdir / "hybrid_example.png")
    if man.get("noise"):
        out["noise"] = Path(man["noise"]).with_suffix(".png")
    return out


#: The figures `build_figures` draws itself (each `{name}.png` in the figures folder), in its order.
DRAWN_FIGURES = ("topview", "poses3d", "pr_curves", "dataset_example", "loss_curves", "pareto", "hybrid_example")


def write_report(man: dict, tables_dir, figures_dir, readme) -> tuple[dict, dict]:
    """Write the tables (each as csv, md, tex), the figures and the summary README, all or none
    (`sonardet.io.atomic.atomic_outputs`: a failing figure leaves the previous report untouched);
    returns (tables, figures), figures as their final paths. A figure that comes out blank is an error."""
    tables_dir, figures_dir, readme = Path(tables_dir), Path(figures_dir), Path(readme)
    tables = build_tables(man)
    table_files = [tables_dir / f"{name}{ext}" for name in tables for ext in TABLE_SUFFIXES]
    figure_files = [figures_dir / f"{name}.png" for name in DRAWN_FIGURES if name in man["figures"]]
    with atomic_outputs(table_files + figure_files + [readme]) as staged:
        staged_tables = staged[0].parent if table_files else tables_dir
        for name, df in tables.items():
            write_table(df, staged_tables / name, caption=man.get("captions", {}).get(name))
        staged_figures = staged[len(table_files)].parent if figure_files else figures_dir
        figures = build_figures(man, tables, staged_figures)
        for name, path in figures.items():
            if not image_is_informative(path):
                raise RuntimeError(f"figure {name} ({figures_dir / Path(path).name}) came out blank")
        final = {n: figures_dir / p.name if p.parent == staged_figures else p for n, p in figures.items()}
        write_results_readme(staged[-1], tables, final, dict(man["config_info"]), machine_info(),
                             title="sonardet results", link_dir=readme.parent)
    return tables, final
