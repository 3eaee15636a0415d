"""Readers for the result files the report is built from (metrics, PR curves, benchmarks, stats).

Each reader accepts a path or, where it makes sense, an already-loaded object, so the table and
figure functions can be called from a workflow (paths) as well as from a notebook (dicts).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from .. import SCHEMA_VERSION
from ..io.artifacts import read_json_file, read_npz, reading

PathLike = str | os.PathLike


def read_json(source) -> dict:
    """A JSON document from a path, or the dict itself when one is given (not copied)."""
    if isinstance(source, dict):
        return source
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"{path}: file not found")
    return read_json_file(path, "result file")


def read_csv_file(path, what: str) -> pd.DataFrame:
    """A CSV table (pandas), errors (truncated, not CSV, not UTF-8) naming the file and the fix."""
    if not Path(path).exists():
        raise FileNotFoundError(f"{path}: file not found ({what})")
    with reading(path, what):
        return pd.read_csv(path)


def read_metrics(source) -> dict:
    """An evaluation `metrics.json` (see sonardet.eval.evaluate_files) or the dict; checks the keys used."""
    m = read_json(source)
    label = source if not isinstance(source, dict) else "<metrics>"
    if m.get("schema_version") not in (None, SCHEMA_VERSION):
        raise ValueError(f"{label}: schema_version {m.get('schema_version')!r} is not {SCHEMA_VERSION}; "
                         "re-run the evaluation with this version of sonardet")
    missing = [k for k in ("classes", "dist_thresholds_m", "headline_m", "mAP", "mAP_headline", "per_class")
               if k not in m]
    if missing:
        raise ValueError(f"{label}: missing key(s) {missing}; expected a metrics.json written by evaluate_files")
    return m


def read_pr_curves(path) -> dict[str, np.ndarray]:
    """PR curves `.npz` written by sonardet.eval.evaluate.write_pr_curves: classes (C,), thresholds_m
    (T,), recall (101,), precision and confidence (C, T, 101)."""
    out = read_npz(path, "PR curves file")
    missing = [k for k in ("classes", "thresholds_m", "recall", "precision") if k not in out]
    if missing:
        raise ValueError(f"{path}: missing array(s) {missing}; expected pr_curves.npz from evaluate_files")
    return out


def read_benchmark(path) -> dict:
    """One Snakemake benchmark `.tsv` (one row: s, h:m:s, max_rss (MB), ...) as a dict of its first row."""
    with reading(path, "Snakemake benchmark file"):
        df = pd.read_csv(path, sep="\t")
    if len(df) == 0 or "s" not in df.columns:
        raise ValueError(f"{path}: expected a Snakemake benchmark file with a header and a row (column 's')")
    return df.iloc[0].to_dict()


def benchmark_summary(paths) -> dict:
    """Mean and max wall-clock seconds and max resident memory (MB) over benchmark files.

    Returns {n, mean_s, max_s, max_rss_mb}; an empty list gives n = 0 and None values. A file whose
    memory column reads 'NA' (possible for very short jobs) does not count towards max_rss_mb.
    """
    rows = [read_benchmark(p) for p in paths]
    if not rows:
        return {"n": 0, "mean_s": None, "max_s": None, "max_rss_mb": None}
    s = np.array([float(r["s"]) for r in rows])
    rss = pd.to_numeric(pd.Series([r.get("max_rss") for r in rows]), errors="coerce").dropna()
    return {"n": len(rows), "mean_s": float(s.mean()), "max_s": float(s.max()),
            "max_rss_mb": float(rss.max()) if len(rss) else None}


def count_annotations(scene_jsons, visible_only: bool = True) -> int:
    """Number of ground-truth objects in scene files (`scenes/{scene}.json` paths or dicts);
    objects with visible == false are left out unless visible_only is False."""
    n = 0
    for s in scene_jsons:
        objs = read_json(s).get("objects", [])
        n += sum(1 for o in objs if o.get("visible", True) or not visible_only)
    return n
