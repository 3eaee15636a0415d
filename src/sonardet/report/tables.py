"""Report tables: pure functions from result files (or loaded dicts) to DataFrames, and a writer that
puts each table out as CSV (full precision), GitHub Markdown and booktabs LaTeX (rounded).

Column names carry their unit or threshold (`mAP@0.5m` is the mean over classes of AP with a 0.5 m
centre-distance match threshold). Rows with the source study's figures are labelled "study".
"""

from __future__ import annotations

import importlib.util
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from ..eval.evaluate import threshold_key
from ..io.atomic import atomic_write_text
from .inputs import benchmark_summary, count_annotations, read_csv_file, read_json, read_metrics
from .study import STUDY, STUDY_SOURCE, study_map

THIS_RUN = "this run"


# ---------------------------------------------------------------------------------------------------
# Formatting and writing


def format_cell(v, na: str = "") -> str:
    """Text of one table cell: integers as is, floats rounded by magnitude (>= 100: 0 decimals,
    >= 10: 1, else 3), missing values (None, NaN, NA) as `na`."""
    if v is None or v is pd.NA or (isinstance(v, (float, np.floating)) and math.isnan(v)):
        return na
    if isinstance(v, (bool, np.bool_)):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        a = abs(float(v))
        if math.isinf(a):
            return str(float(v))
        if a >= 100:
            return f"{v:.0f}"
        if a >= 10:
            return f"{v:.1f}"
        if 0 < a < 1e-3:
            return f"{v:.1e}"
        return f"{v:.3f}"
    return str(v)


def _is_numeric(s: pd.Series) -> bool:
    return pd.api.types.is_numeric_dtype(s) and not pd.api.types.is_bool_dtype(s)


def _formatted(df: pd.DataFrame, na: str) -> pd.DataFrame:
    return pd.DataFrame({c: [format_cell(v, na) for v in df[c].tolist()] for c in df.columns}, dtype=object)


def markdown_table(df: pd.DataFrame, caption: str | None = None) -> str:
    """GitHub-flavoured Markdown of a table (numbers right-aligned, rounded by `format_cell`)."""
    cells = _formatted(df, "")
    esc = lambda s: str(s).replace("|", "\\|").replace("\n", " ")  # noqa: E731
    lines = []
    if caption:
        lines += [f"*{esc(caption)}*", ""]
    lines.append("| " + " | ".join(esc(c) for c in df.columns) + " |")
    lines.append("|" + "|".join("---:" if _is_numeric(df[c]) else ":---" for c in df.columns) + "|")
    for _, row in cells.iterrows():
        lines.append("| " + " | ".join(esc(v) for v in row.tolist()) + " |")
    return "\n".join(lines) + "\n"


_LATEX_SPECIAL = {"&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{", "}": r"\}",
                  "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "\\": r"\textbackslash{}"}


def latex_escape(s: str) -> str:
    """Escape LaTeX special characters in plain text."""
    return re.sub(r"[&%$#_{}~^\\]", lambda m: _LATEX_SPECIAL[m.group(0)], str(s))


def _latex_by_hand(cells: pd.DataFrame, column_format: str, caption: str | None, label: str | None) -> str:
    out = []
    if caption is not None:
        out += ["\\begin{table}", f"\\caption{{{caption}}}"]
        if label:
            out.append(f"\\label{{{label}}}")
    out += [f"\\begin{{tabular}}{{{column_format}}}", "\\toprule",
            " & ".join(latex_escape(c) for c in cells.columns) + " \\\\", "\\midrule"]
    for _, row in cells.iterrows():
        out.append(" & ".join(latex_escape(v) for v in row.tolist()) + " \\\\")
    out += ["\\bottomrule", "\\end{tabular}"]
    if caption is not None:
        out.append("\\end{table}")
    return "\n".join(out) + "\n"


def latex_table(df: pd.DataFrame, caption: str | None = None, label: str | None = None,
                use_pandas: bool | None = None) -> str:
    """Booktabs LaTeX of a table (needs \\usepackage{booktabs}); in a `table` float when a caption is
    given. Uses pandas `to_latex` when jinja2 is importable (use_pandas None: auto), else a small
    writer of the same layout. Missing values print as '--'."""
    cells = _formatted(df, "--")
    column_format = "".join("r" if _is_numeric(df[c]) else "l" for c in df.columns)
    cap = latex_escape(caption) if caption is not None else None
    if use_pandas is None:
        use_pandas = importlib.util.find_spec("jinja2") is not None  # pandas' to_latex needs jinja2
    if not use_pandas:
        return _latex_by_hand(cells, column_format, cap, label)
    # pandas would also put a \label without a caption; keep both writers' layout the same.
    return cells.to_latex(index=False, escape=True, column_format=column_format, caption=cap,
                          label=label if cap is not None else None)


#: The files of one table, `{stem}{suffix}` each (`write_table`).
TABLE_SUFFIXES = (".csv", ".md", ".tex")


def write_table(df: pd.DataFrame, stem, caption: str | None = None) -> list[Path]:
    """Write a table as `{stem}.csv` (full precision, missing values empty), `{stem}.md` (GitHub
    Markdown) and `{stem}.tex` (booktabs, label `tab:{stem name}`), each atomically. Returns the paths."""
    stem = Path(stem)
    paths = [stem.with_name(stem.name + ext) for ext in TABLE_SUFFIXES]
    atomic_write_text(paths[0], df.to_csv(index=False, lineterminator="\n"))
    atomic_write_text(paths[1], markdown_table(df, caption))
    atomic_write_text(paths[2], latex_table(df, caption, label=f"tab:{stem.name}"))
    return paths


# ---------------------------------------------------------------------------------------------------
# Tables


def _counts_as_int(df: pd.DataFrame, cols) -> pd.DataFrame:
    for c in cols:
        if c in df.columns:
            df[c] = pd.array([None if pd.isna(v) else int(v) for v in df[c]], dtype="Int64")
    return df


def _mAP_col(headline_m: float) -> str:
    return f"mAP@{threshold_key(headline_m)}m"


#: Columns of a trained method's budget (train.json), in comparison tables.
BUDGET_COLUMNS = ("epochs", "steps", "n_points", "n_parameters", "device", "train_s")


def comparison_table(metrics: dict, classes=None, study: bool = True, intervals: dict | None = None,
                     budgets: dict | None = None) -> pd.DataFrame:
    """One row per method (insertion order of `metrics`: method -> metrics.json path or dict).

    Columns: method, source ('this run' or 'source study'), mAP@{headline}m, map_low and map_high (the
    bootstrap interval, from `intervals`: method -> (low, high); empty without), predictions (all
    classes), ground truth (visible objects, all classes), `AP@{headline}m {cls}` for each class
    (default: the first metrics' classes), mAP at every other threshold, then a trained method's budget
    (`budgets`: method -> train.json path or dict): epochs, steps, n_points, n_parameters, device,
    train_s. With study=True the source study's rows follow (mAP, predictions, per-class AP).
    """
    loaded = {k: read_metrics(v) for k, v in metrics.items()}
    first = next(iter(loaded.values()), None)
    headline = first["headline_m"] if first else 0.5
    if classes is None:
        classes = list(first["classes"]) if first else []
    hk = threshold_key(headline)
    other = [t for t in (first["dist_thresholds_m"] if first else []) if float(t) != float(headline)]
    cols = (["method", "source", _mAP_col(headline), "map_low", "map_high", "predictions", "ground truth"]
            + [f"AP@{hk}m {c}" for c in classes] + [f"mAP@{threshold_key(t)}m" for t in other]
            + (list(BUDGET_COLUMNS) if budgets else []))
    rows = [_comparison_row(method, m, headline, classes, other, (intervals or {}).get(method),
                            (budgets or {}).get(method)) for method, m in loaded.items()]
    if study:
        for name, fig in STUDY["comparison"].items():
            rows.append({"method": name, "source": STUDY_SOURCE, _mAP_col(headline): fig["mAP"],
                         "predictions": fig["predictions"],
                         **{f"AP@{hk}m {c}": v for c, v in fig.get("AP", {}).items() if c in classes}})
    df = pd.DataFrame(rows, columns=cols)
    return _counts_as_int(df, ["predictions", "ground truth"] + (["epochs", "steps", "n_points", "n_parameters"]
                                                                  if budgets else []))


def _comparison_row(method: str, m: dict, headline: float, classes, other, interval, budget) -> dict:
    if float(m["headline_m"]) != float(headline):
        raise ValueError(f"metrics of {method!r} use headline threshold {m['headline_m']} m, the first "
                         f"ones {headline} m; evaluate every method with the same settings")
    hk = threshold_key(headline)
    pc = m["per_class"]
    row = {"method": method, "source": THIS_RUN, _mAP_col(headline): m["mAP_headline"],
           "predictions": sum(int(v["n_pred"]) for v in pc.values()),
           "ground truth": sum(int(v["n_gt"]) for v in pc.values())}
    if interval is not None:
        row["map_low"], row["map_high"] = float(interval[0]), float(interval[1])
    for c in classes:
        row[f"AP@{hk}m {c}"] = pc[c]["AP"][hk] if c in pc else np.nan
    for t in other:
        row[f"mAP@{threshold_key(t)}m"] = m["mAP"].get(threshold_key(t), np.nan)
    if budget is not None:
        b = read_json(budget)
        row.update(epochs=b.get("epochs"), steps=b.get("steps"),
                   n_points=b.get("n_points", (b.get("params") or {}).get("n_points")),
                   n_parameters=b.get("n_parameters"), device=b.get("device"), train_s=b.get("train_time_s"))
    return row


def differences_table(compares: dict, scoring: str = "all") -> pd.DataFrame:
    """Paired bootstrap differences to the reference method on each dataset (compare/{dataset}.json,
    path or dict, by dataset): one row per (dataset, method): its mAP, the reference's, the difference
    and its interval, and whether the interval excludes 0 (a ranking the data support)."""
    rows = []
    for dataset, src in compares.items():
        c = read_json(src)
        ref = c["reference"]
        for method, r in c["scorings"][scoring].items():
            if "diff" not in r:
                continue
            d = r["diff"]
            rows.append({"test set": dataset, "method": method, "mAP": r["mAP"], "vs": ref,
                         "mAP vs": c["scorings"][scoring][ref]["mAP"], "difference": d["mAP"],
                         "difference low": d["low"], "difference high": d["high"],
                         "resolved": bool(d["low"] > 0 or d["high"] < 0), "scenes": c["n_scenes"]})
    return pd.DataFrame(rows, columns=["test set", "method", "mAP", "vs", "mAP vs", "difference", "difference low",
                                       "difference high", "resolved", "scenes"])


def scoring_table(compare, methods, scorings=("all", "accepted", "dont_care")) -> pd.DataFrame:
    """One row per method: its mAP and bootstrap interval under each scoring of a compare JSON (all
    boxes; accepted boxes only; don't-care objects ignored)."""
    c = read_json(compare)
    rows = []
    for m in methods:
        row = {"method": m}
        for s in scorings:
            r = c["scorings"].get(s, {}).get(m)
            if r is not None:
                row.update({f"mAP {s}": r["mAP"], f"low {s}": r["low"], f"high {s}": r["high"]})
        rows.append(row)
    return pd.DataFrame(rows)


def ladder_table(steps: list[dict], compare) -> pd.DataFrame:
    """The improvement ladder: steps [{method, step (what it adds), scoring ('all' or 'accepted'),
    seconds (s/scene list)}] in order, each with its mAP and bootstrap interval (compare JSON of the
    synthetic test set), the change against the step before and its s/scene."""
    c = read_json(compare)
    rows, prev = [], None
    for st in steps:
        r = c["scorings"][st["scoring"]][st["method"]]
        secs = st.get("seconds") or []
        rows.append({"step": st["step"], "method": st["method"], "boxes": st["scoring"], "mAP@0.5m": r["mAP"],
                     "map_low": r["low"], "map_high": r["high"],
                     "change": np.nan if prev is None else r["mAP"] - prev,
                     "s/scene": float(np.mean(secs)) if len(secs) else np.nan})
        prev = r["mAP"]
    return pd.DataFrame(rows)


def realism_ablation_table(rows, headline_m: float = 0.5) -> pd.DataFrame:
    """The one-at-a-time realism ablation (rows of `realism_ablation/summary.json`, path or list): one
    row per effect ('none' = plain sensor first, 'all' = every effect last, the others by the largest
    loss of any method), columns `mAP@{h}m {method}` and `change {method}` (mAP minus the plain
    sensor's) per method, and the realism_test keys the effect switches on."""
    rows = read_json(rows) if not isinstance(rows, list) else rows
    if not rows:
        raise ValueError("realism ablation: no rows")
    methods = list(dict.fromkeys(r["method"] for r in rows))
    col = _mAP_col(headline_m)
    by = {}
    for r in rows:
        e = by.setdefault(r["effect"], {"effect": r["effect"], "keys": ", ".join(r.get("keys", []))})
        e[f"{col} {r['method']}"] = r["mAP"]
        e[f"change {r['method']}"] = r["delta_mAP"]
    effects = [e for e in by if e not in ("none", "all")]
    effects.sort(key=lambda e: (min(by[e][f"change {m}"] for m in methods), e))
    order = [e for e in ["none"] if e in by] + effects + [e for e in ["all"] if e in by]
    cols = ["effect"] + [f"{col} {m}" for m in methods] + [f"change {m}" for m in methods] + ["keys"]
    return pd.DataFrame([by[e] for e in order], columns=cols)


def domain_randomisation_table(metrics: dict, pairs: dict) -> pd.DataFrame:
    """SASA with and without domain randomisation on every test set.

    metrics: dataset -> {method -> metrics.json path or dict}; pairs: DR method -> plain method (e.g.
    'sasa_dr_100' -> 'sasa_100'). One row per (dataset, pair): mAP of both and the change."""
    rows = []
    for dataset, by_method in metrics.items():
        for dr, plain in pairs.items():
            a, b = read_metrics(by_method[plain]), read_metrics(by_method[dr])
            col = _mAP_col(a["headline_m"])
            rows.append({"test set": dataset, "model": plain, f"{col} plain": a["mAP_headline"],
                         f"{col} with DR": b["mAP_headline"], "change": b["mAP_headline"] - a["mAP_headline"]})
    return pd.DataFrame(rows)


def fraction_table(methods: list[dict], metrics: dict, scenes_dir=None) -> pd.DataFrame:
    """Each trained method at its training fraction beside the training-free methods.

    methods: one dict per method, {name, family, trained, fraction, training (label), summary
    (trained: `models/{method}/train.json` path or dict), annotations (optional: training annotations,
    else counted from the summary's `train_scenes` in scenes_dir when given)}. metrics: method ->
    metrics.json path or dict (a method without one gets NaN). Rows: trained methods by ascending
    fraction, then the untrained ones with 0 training scenes, in the given order. The study's mAP of
    the same family and fraction (sonardet.report.study) is set beside.
    Columns: method, training, training data (%), training scenes, training annotations,
    mAP@{headline}m, mAP@{headline}m (study).
    """
    loaded = {k: read_metrics(v) for k, v in metrics.items()}
    headline = next(iter(loaded.values()))["headline_m"] if loaded else 0.5
    col, scol = _mAP_col(headline), _mAP_col(headline) + " (study)"
    rows = []
    trained = sorted((m for m in methods if m["trained"]), key=lambda m: int(m["fraction"]))
    for m in trained:
        s = read_json(m["summary"])
        n_ann = m.get("annotations")
        if n_ann is None and scenes_dir is not None and s.get("train_scenes"):
            n_ann = count_annotations(Path(scenes_dir) / f"{sid}.json" for sid in s["train_scenes"])
        got = loaded.get(m["name"])
        rows.append({"method": m["name"], "training": m["training"], "training data (%)": int(m["fraction"]),
                     "training scenes": s.get("n_train_scenes"), "training annotations": n_ann,
                     col: got["mAP_headline"] if got else np.nan, scol: study_map(m["family"], m["fraction"])})
    for m in methods:
        if not m["trained"] and m["name"] in loaded:
            rows.append({"method": m["name"], "training": m["training"], "training data (%)": 0,
                         "training scenes": 0, "training annotations": 0, col: loaded[m["name"]]["mAP_headline"],
                         scol: study_map(m["family"], None)})
    cols = ["method", "training", "training data (%)", "training scenes", "training annotations", col, scol]
    df = pd.DataFrame(rows, columns=cols)
    return _counts_as_int(df, ["training data (%)", "training scenes", "training annotations"])


def _stage_rows(method: str, stats: list[dict], mem_mb) -> list[dict]:
    stages: list[str] = []
    for s in stats:
        stages += [k for k in s.get("seconds", {}) if k not in stages]
    if "total" in stages:  # total last
        stages = [k for k in stages if k != "total"] + ["total"]
    rows = []
    for st in stages:
        v = np.array([float(s["seconds"][st]) for s in stats if st in s.get("seconds", {})])
        rows.append({"method": method, "stage": st, "unit": "s/scene", "n": len(v), "mean": float(v.mean()),
                     "max": float(v.max()), "peak memory (MB)": mem_mb if st == "total" else np.nan})
    return rows


def timing_table(per_scene_stats: dict | None = None, per_dataset_timing: dict | None = None,
                 train_summaries: dict | None = None, simulation_benchmarks=None, scene_jsons=None,
                 benchmarks: dict | None = None) -> pd.DataFrame:
    """Run time and memory per method and stage (seconds, MB), one row per (method, stage).

    per_scene_stats: method -> list of per-scene `stats/{method}/{dataset}/{scene}.json` (paths or
      dicts) of a per-scene method; gives mean and max over scenes of every entry of `seconds`
      (ground, proposals, registration, ..., total last), unit s/scene.
    per_dataset_timing: method -> `stats/{method}/{dataset}/inference.json` of a per-dataset method;
      stage 'inference', s/scene (mean only), peak memory from its peak_rss_mb.
    train_summaries: method -> `models/{method}/train.json`; stages 'training' (s, total training time)
      and 'training step' (s/step), peak memory from peak_rss_mb.
    simulation_benchmarks: Snakemake benchmark `.tsv` files of the scene simulation jobs, {file: number
      of scenes its job made} (a list: one scene each); stage 'scene (benchmark)', s/scene (a job's
      wall time, start-up included, shared by its scenes; max: the slowest job's), peak memory = max
      of max_rss.
    scene_jsons: `scenes/{scene}.json` (paths or dicts); their `timings_s` give the simulator's stages
      (seabed, layout, physics, scan, ...), s/scene.
    benchmarks: method -> benchmark `.tsv` files of its detection jobs; their max_rss fills the
      method's peak memory where the stats do not give one.
    Columns: method, stage, unit, n (files averaged), mean, max, peak memory (MB).
    """
    rows = []
    bench_mem = {m: benchmark_summary(p)["max_rss_mb"] for m, p in (benchmarks or {}).items()}
    for method, files in (per_scene_stats or {}).items():
        stats = [read_json(f) for f in files]
        if stats:
            rows += _stage_rows(method, stats, bench_mem.get(method, np.nan))
    for method, src in (per_dataset_timing or {}).items():
        d = read_json(src)
        mem = d.get("peak_rss_mb", bench_mem.get(method, np.nan))
        rows.append({"method": method, "stage": "inference", "unit": "s/scene", "n": d.get("n_scenes"),
                     "mean": d.get("s_per_scene"), "max": np.nan, "peak memory (MB)": mem})
    for method, src in (train_summaries or {}).items():
        d = read_json(src)
        rows.append({"method": method, "stage": "training", "unit": "s", "n": d.get("n_train_scenes"),
                     "mean": d.get("train_time_s"), "max": np.nan, "peak memory (MB)": d.get("peak_rss_mb")})
        rows.append({"method": method, "stage": "training step", "unit": "s/step", "n": d.get("steps"),
                     "mean": d.get("s_per_step"), "max": np.nan, "peak memory (MB)": np.nan})
    rows += _simulation_rows(scene_jsons, simulation_benchmarks)
    cols = ["method", "stage", "unit", "n", "mean", "max", "peak memory (MB)"]
    df = pd.DataFrame(rows, columns=cols)
    for c in ("mean", "max", "peak memory (MB)"):
        df[c] = pd.to_numeric(df[c], errors="coerce").astype(float)
    return _counts_as_int(df, ["n"])


def _simulation_rows(scene_jsons, simulation_benchmarks) -> list[dict]:
    rows = []
    sims = [read_json(s) for s in (scene_jsons or [])]
    if sims:
        keys: list[str] = []
        for s in sims:
            keys += [k for k in s.get("timings_s", {}) if k not in keys]
        for k in keys:
            v = np.array([float(s["timings_s"][k]) for s in sims if k in s.get("timings_s", {})])
            rows.append({"method": "simulation", "stage": k.removesuffix("_s"), "unit": "s/scene", "n": len(v),
                         "mean": float(v.mean()), "max": float(v.max()), "peak memory (MB)": np.nan})
    if simulation_benchmarks:
        # {benchmark file: scenes its job made} (a list: one scene each); s/scene = a job's wall time
        # over its scenes, start-up included; max: the slowest job's share per scene.
        jobs = simulation_benchmarks if isinstance(simulation_benchmarks, dict) else \
            {p: 1 for p in simulation_benchmarks}
        per_job = [(benchmark_summary([p]), int(n)) for p, n in jobs.items()]
        n = sum(k for _, k in per_job)
        rss = [b["max_rss_mb"] for b, _ in per_job if b["max_rss_mb"] is not None]
        rows.append({"method": "simulation", "stage": "scene (benchmark)", "unit": "s/scene", "n": n,
                     "mean": sum(b["mean_s"] for b, _ in per_job) / n,
                     "max": max(b["mean_s"] / k for b, k in per_job),
                     "peak memory (MB)": max(rss) if rss else np.nan})
    return rows


def dataset_table(stats_csv) -> pd.DataFrame:
    """`tables/dataset_stats.csv` (path or DataFrame) reshaped for the report, the study's figures beside.

    Columns: split, scenes, objects, (not visible, when present), one column per class holding
    'count (share %)', scenes (study), objects (study). The study reports 100 scenes (80 train /
    20 test) and 5491 objects in all.
    """
    src = stats_csv if isinstance(stats_csv, pd.DataFrame) else read_csv_file(stats_csv, "dataset table")
    classes = [c.removesuffix("_share_pct") for c in src.columns if c.endswith("_share_pct")]
    out = pd.DataFrame({"split": src["split"].astype(str), "scenes": src["scenes"], "objects": src["objects"]})
    if "objects_not_visible" in src.columns:
        out["not visible"] = src["objects_not_visible"]
    for c in classes:
        out[c] = [f"{int(n)} ({p:.1f} %)" for n, p in zip(src[c], src[f"{c}_share_pct"])]
    sd = STUDY["dataset"]
    out["scenes (study)"] = [sd["scenes"].get(s) for s in out["split"]]
    out["objects (study)"] = [sd["objects"].get(s) for s in out["split"]]
    return _counts_as_int(out, ["scenes", "objects", "not visible", "scenes (study)", "objects (study)"])


def seeds_table(groups: dict) -> pd.DataFrame:
    """A trained method at several seeds (groups: main method -> {method: metrics.json path or dict},
    the main one first): one row per group with the mAP of each seed, their mean, standard deviation
    (ddof 1), minimum and maximum."""
    rows = []
    for main, metrics in groups.items():
        maps = [read_metrics(m)["mAP_headline"] for m in metrics.values()]
        rows.append({"method": main, "seeds": len(maps), "mAP mean": float(np.mean(maps)),
                     "mAP std": float(np.std(maps, ddof=1)) if len(maps) > 1 else np.nan,
                     "mAP min": float(np.min(maps)), "mAP max": float(np.max(maps)),
                     "mAP per seed": ", ".join(f"{v:.3f}" for v in maps)})
    return pd.DataFrame(rows)


def breakdown_table(compare) -> pd.DataFrame:
    """The model-mismatch breakdown (compare JSON's `perturbation_breakdown`): one row per perturbation
    bin, the number of objects and classes in it, and every method's mAP over them."""
    c = read_json(compare)
    rows = []
    for name, b in c.get("perturbation_breakdown", {}).items():
        rows.append({"perturbation": name, "objects": b["n_objects"], "classes": ", ".join(b["classes"]),
                     **{f"mAP {m}": v for m, v in b["methods"].items()}})
    return pd.DataFrame(rows)
