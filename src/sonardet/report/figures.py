"""Report figures: each function writes one PNG (about 120 dpi) from result files and returns its path.

Scene figures (top view, 3D poses, dataset example) live in `scene_figures` and are re-exported here.
Colours are fixed per class and per method (`style`), so the same method looks the same everywhere.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from .inputs import read_csv_file, read_pr_curves
from .scene_figures import plot_3d_poses, plot_dataset_example, plot_topview
from .style import OKABE_ITO, method_family, method_style, new_figure, write_figure

__all__ = [
    "image_is_informative",
    "pareto_front",
    "plot_3d_poses",
    "plot_dataset_example",
    "plot_loss_curves",
    "plot_noise",
    "plot_pareto",
    "plot_pr_curves",
    "plot_topview",
]


def _fraction_label(key) -> str:
    s = str(key).strip().rstrip("%")
    return s.rsplit("_", 1)[-1]


# ---------------------------------------------------------------------------------------------------
# Precision/recall and training curves


def plot_pr_curves(pr_files: dict, classes, out_png, threshold: float = 0.5) -> Path:
    """Precision-recall curves at one centre-distance threshold (m): one panel per class, one line per
    method. pr_files: method -> `eval/{method}/{dataset}/pr_curves.npz` path; classes: names to show
    (None: those of the first file). The curves are the devkit's interpolated ones (101 recall
    points), ending at the highest recall the method reached. Returns out_png."""
    curves = {m: read_pr_curves(p) for m, p in pr_files.items()}
    if classes is None:
        first = next(iter(curves.values()), None)
        classes = [str(c) for c in first["classes"]] if first is not None else []
    classes = list(classes) or ["(no class)"]
    ncols = min(len(classes), 4)
    nrows = int(np.ceil(len(classes) / ncols))
    fig = new_figure(3.3 * ncols, 3.2 * nrows + 0.5)
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=True, sharey=True).ravel()
    for ax, cls in zip(axes, classes):
        for method, c in curves.items():
            names = [str(x) for x in c["classes"]]
            tj = np.flatnonzero(np.isclose(c["thresholds_m"], float(threshold)))
            if cls not in names or len(tj) == 0:
                continue
            prec = c["precision"][names.index(cls), int(tj[0])]
            rec = c["recall"]
            if "confidence" in c:
                # Interpolated confidence 0 marks recall the detector never reached: end the curve there.
                reached = c["confidence"][names.index(cls), int(tj[0])] > 0
                prec, rec = prec[reached], rec[reached]
            st = method_style(method)
            ax.plot(rec, prec, color=st["color"], ls=st["linestyle"], lw=1.6, label=method)
        ax.set_title(cls, fontsize=10)
        ax.set_xlim(0, 1.0)
        ax.set_ylim(0, 1.03)
        ax.grid(alpha=0.3)
        ax.set_xlabel("recall")
        ax.set_ylabel("precision")
    for ax in axes[len(classes):]:
        ax.set_axis_off()
    handles = [Line2D([], [], color=method_style(m)["color"], ls=method_style(m)["linestyle"], lw=1.6, label=m)
               for m in curves]
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 5), fontsize=8)
    fig.suptitle(f"precision-recall, centre-distance threshold {float(threshold):g} m")
    return write_figure(fig, out_png)


def plot_loss_curves(loss_csvs: dict, out_png) -> Path:
    """Training loss per epoch of SASA at each data fraction (left) and the development-set mAP where
    `loss.csv` has a `val_mAP` column (right). loss_csvs: fraction (25, '25' or 'sasa_25') ->
    `models/sasa_{f}/loss.csv` path or DataFrame with columns epoch, loss, ... Returns out_png."""
    frames = {}
    for k, src in sorted(loss_csvs.items(), key=lambda kv: float(_fraction_label(kv[0]))):
        df = src if isinstance(src, pd.DataFrame) else read_csv_file(src, "loss curve (loss.csv)")
        if "epoch" not in df.columns or "loss" not in df.columns:
            raise ValueError(f"{src}: loss.csv needs columns 'epoch' and 'loss', has {list(df.columns)}")
        frames[_fraction_label(k)] = df
    has_val = any("val_mAP" in d.columns and d["val_mAP"].notna().any() for d in frames.values())
    fig = new_figure(9.5 if has_val else 5.5, 4.0)
    axes = fig.subplots(1, 2 if has_val else 1, squeeze=False).ravel()
    lo, hi = np.inf, -np.inf
    for f, df in frames.items():
        st = method_style(f"sasa_{f}")
        loss = df["loss"].astype(float)
        lo, hi = min(lo, loss.min()), max(hi, loss.max())
        axes[0].plot(df["epoch"], loss, color=st["color"], ls="-", marker=st["marker"], ms=3, label=f"{f} % of data")
        if has_val and "val_mAP" in df.columns:
            v = df[df["val_mAP"].notna()]
            axes[1].plot(v["epoch"], v["val_mAP"].astype(float), color=st["color"], ls=st["linestyle"],
                         marker=st["marker"], label=f"{f} % of data")
    if np.isfinite(lo) and lo > 0 and hi / lo > 20:
        axes[0].set_yscale("log")
    for ax in axes:
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    axes[0].set_xlabel("epoch")
    axes[0].set_ylabel("training loss (mean over steps)")
    axes[0].set_title("SASA training loss")
    axes[0].grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    if has_val:
        axes[1].set_xlabel("epoch")
        axes[1].set_ylabel("dev mAP (headline threshold)")
        axes[1].set_ylim(0, 1.02)
        axes[1].set_title("SASA mAP on the development scenes")
        axes[1].grid(alpha=0.3)
        axes[1].legend(fontsize=8)
    return write_figure(fig, out_png)


# ---------------------------------------------------------------------------------------------------
# Speed versus accuracy


def pareto_front(df: pd.DataFrame, x: str, y: str) -> np.ndarray:
    """Boolean mask (len(df),) of the points no other point dominates when x is minimised and y
    maximised (a point dominates another if it is no worse in both and better in one). Rows with a
    missing or non-finite x or y are never on the front; identical points are both on it."""
    xs = pd.to_numeric(df[x], errors="coerce").to_numpy(dtype=float)
    ys = pd.to_numeric(df[y], errors="coerce").to_numpy(dtype=float)
    ok = np.isfinite(xs) & np.isfinite(ys)
    xv, yv = xs[ok], ys[ok]
    no_worse = (xv[None, :] <= xv[:, None]) & (yv[None, :] >= yv[:, None])
    better = (xv[None, :] < xv[:, None]) | (yv[None, :] > yv[:, None])
    dominated = (no_worse & better).any(axis=1)
    mask = np.zeros(len(df), dtype=bool)
    mask[np.flatnonzero(ok)] = ~dominated
    return mask


_FAMILY_MARKERS = {"model-based": "o", "SASA": "^", "other": "s"}
_FAMILY_COLORS = {"model-based": OKABE_ITO["orange"], "SASA": OKABE_ITO["blue"], "other": "#777777"}


def _family(value: str) -> str:
    return value if value in _FAMILY_MARKERS else method_family(value)


def plot_pareto(df: pd.DataFrame, out_png, x: str = "seconds_per_scene", y: str = "mAP", label_col: str = "name",
                default_mask=None, family_col: str = "method") -> Path:
    """Accuracy versus run time of ablation settings: scatter of y (e.g. mAP@0.5 m) against x (e.g.
    seconds per scene), markers per method family, the Pareto front (least time, most accuracy) drawn
    as a step line with its points ringed, and the default settings drawn as stars.

    df: one row per setting (e.g. sonardet.ablation points: name, method, mAP, seconds_per_scene,
    default) with columns x, y, label_col and, optionally, family_col: a method id ('sasa',
    'model_based_ours', ...) or a family name ('model-based', 'SASA'); without it the family is read
    from the label. default_mask: boolean array, or the name of a boolean column, marking the default
    settings; None uses a 'default' column when there is one. Returns out_png.
    """
    if default_mask is None and "default" in df.columns:
        default_mask = "default"
    if isinstance(default_mask, str):
        default_mask = df[default_mask].fillna(False).to_numpy(dtype=bool)
    default_mask = np.zeros(len(df), bool) if default_mask is None else np.asarray(default_mask, dtype=bool)
    labels = df[label_col].astype(str).tolist() if label_col in df.columns else [str(i) for i in range(len(df))]
    fams = [_family(v) for v in (df[family_col].astype(str).tolist() if family_col in df.columns else labels)]
    xs = pd.to_numeric(df[x], errors="coerce").to_numpy(dtype=float)
    ys = pd.to_numeric(df[y], errors="coerce").to_numpy(dtype=float)
    front = pareto_front(df, x, y)

    fig = new_figure(6.8, 4.8)
    ax = fig.subplots()
    for fam in dict.fromkeys(fams):
        m = np.array([f == fam for f in fams]) & ~default_mask
        ax.scatter(xs[m], ys[m], marker=_FAMILY_MARKERS.get(fam, "s"), s=36,
                   color=_FAMILY_COLORS.get(fam, "#777777"), alpha=0.85, label=fam, zorder=3)
        md = np.array([f == fam for f in fams]) & default_mask
        if md.any():
            ax.scatter(xs[md], ys[md], marker="*", s=220, color=_FAMILY_COLORS.get(fam, "#777777"),
                       edgecolors="black", linewidths=0.8, label=f"{fam} default", zorder=5)
    if front.any():
        order = np.argsort(xs[front], kind="stable")
        fx, fy = xs[front][order], ys[front][order]
        ax.step(fx, fy, where="post", color="black", lw=1.0, ls="--", zorder=2, label="Pareto front")
        ax.scatter(fx, fy, s=110, facecolors="none", edgecolors="black", linewidths=1.0, zorder=4)
    if len(df) <= 30:
        for xi, yi, lb in zip(xs, ys, labels):
            if np.isfinite(xi) and np.isfinite(yi):
                ax.annotate(lb, (xi, yi), textcoords="offset points", xytext=(4, 3), fontsize=6)
    finite = xs[np.isfinite(xs) & (xs > 0)]
    if len(finite) and finite.max() / finite.min() > 20:
        ax.set_xscale("log")
    ax.set_xlabel(f"{x.replace('_', ' ')} (s)" if "second" in x or x.endswith("_s") else x)
    ax.set_ylabel(y)
    ax.set_title("accuracy versus run time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    return write_figure(fig, out_png)


# ---------------------------------------------------------------------------------------------------
# Noise characterisation


def _normal_pdf(x, mean, sigma):
    sigma = max(float(sigma), 1e-12)
    return np.exp(-0.5 * ((x - mean) / sigma) ** 2) / (sigma * np.sqrt(2 * np.pi))


def _stat(result: dict, when: str, what: str, fallback) -> float:
    """mean/sigma before/after trimming: flat keys (`mean_before`), or the nested form of
    sonardet.eval.noise (`before: {mean_m, std_m}`), else computed from the distances."""
    v = result.get(f"{what}_{when}")
    if v is None and isinstance(result.get(when), dict):
        v = result[when].get("mean_m" if what == "mean" else "std_m")
    return float(fallback if v is None else v)


def _noise_panel(ax, result: dict, bins):
    d = np.asarray(result["distances_m"], dtype=float)
    kept = np.asarray(result.get("kept_mask", np.ones(len(d), bool)), dtype=bool)
    mb = _stat(result, "before", "mean", np.mean(d) if len(d) else 0.0)
    sb = _stat(result, "before", "sigma", np.std(d) if len(d) else 0.0)
    ma = _stat(result, "after", "mean", np.mean(d[kept]) if kept.any() else 0.0)
    sa = _stat(result, "after", "sigma", np.std(d[kept]) if kept.any() else 0.0)
    mm = 1e3  # plot in millimetres: the spread is centimetres
    ax.hist(d * mm, bins=bins, density=True, color="#9a9a9a", alpha=0.6,
            label=f"all ({len(d):,}): mean {mb * mm:.1f} mm, sigma {sb * mm:.1f} mm")
    ax.hist(d[kept] * mm, bins=bins, density=True, histtype="step", lw=1.5, color=OKABE_ITO["blue"],
            label=f"after trimming ({int(kept.sum()):,}): mean {ma * mm:.1f} mm, sigma {sa * mm:.1f} mm")
    grid = np.linspace(bins[0], bins[-1], 400)
    ax.plot(grid, _normal_pdf(grid, mb * mm, sb * mm), color="black", ls="--", lw=1.1, label="normal fit, all")
    ax.plot(grid, _normal_pdf(grid, ma * mm, sa * mm), color=OKABE_ITO["vermillion"], ls="-", lw=1.3,
            label="normal fit, trimmed")
    ax.set_xlabel("point-to-plane distance (mm)")
    ax.set_ylabel("density (1/mm)")
    ax.set_title(str(result.get("name", "")), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6.5, loc="upper left")  # the distribution peaks in the middle


def plot_noise(result: dict, out_png, simulated: dict | None = None) -> Path:
    """Noise characterisation: histogram of point-to-plane distances before and after z-score
    trimming with the fitted normal curves (mean and sigma in the legend, in mm).

    result: {distances_m (N,), kept_mask (N,) bool, mean_before, sigma_before, mean_after, sigma_after
    (m), name}, or a sonardet.eval.noise.characterize_noise result (statistics under before/after);
    missing statistics are computed from the distances. simulated: an optional second
    result of the same form (the simulator's), drawn in a panel beside on the same axis range.
    Returns out_png.
    """
    results = [result] + ([simulated] if simulated is not None else [])
    alld = np.concatenate([np.asarray(r["distances_m"], dtype=float) for r in results]) * 1e3
    lo, hi = (np.percentile(alld, [0.2, 99.8]) if len(alld) else (-1.0, 1.0))
    if hi <= lo:
        lo, hi = lo - 1.0, hi + 1.0
    bins = np.linspace(lo, hi, 61)
    fig = new_figure(5.6 * len(results), 4.2)
    axes = fig.subplots(1, len(results), squeeze=False, sharex=True).ravel()
    for ax, r in zip(axes, results):
        _noise_panel(ax, r, bins)
    return write_figure(fig, out_png)


# ---------------------------------------------------------------------------------------------------
# Checks


def image_is_informative(png, min_std: float = 0.02, min_colors: int = 2) -> bool:
    """True if an image file is not blank: the standard deviation of its grey values (0..1, alpha
    composited over white) exceeds min_std and it has at least min_colors distinct colours."""
    import matplotlib.image as mpimg

    raw = mpimg.imread(str(png))
    img = raw.astype(np.float64)
    if raw.dtype.kind in "ui":  # PNGs load as floats in 0..1, other formats as integers
        img /= float(np.iinfo(raw.dtype).max)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[-1] in (2, 4):
        alpha = img[..., -1:]
        img = img[..., :-1] * alpha + (1.0 - alpha)
    grey = img.mean(axis=-1)
    n_colors = len(np.unique(np.round(img.reshape(-1, img.shape[-1]) * 255).astype(np.int32), axis=0))
    return bool(grey.std() > min_std and n_colors >= min_colors)
