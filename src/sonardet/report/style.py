"""Fixed, colour-blind-safe colours and line styles per class and per method, and figure saving.

Colours come from the Okabe-Ito palette, so every figure of a report uses the same colour for the
same class or method. Figures are built on `matplotlib.figure.Figure` directly (Agg canvas), never
through pyplot: no display is needed and no global figure state leaks between calls.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..io.atomic import atomic_path

#: Okabe-Ito palette (Wong 2011, Nature Methods 8:441).
OKABE_ITO = {
    "black": "#000000",
    "orange": "#E69F00",
    "sky_blue": "#56B4E9",
    "green": "#009E73",
    "yellow": "#F0E442",
    "blue": "#0072B2",
    "vermillion": "#D55E00",
    "purple": "#CC79A7",
}

CLASS_COLORS = {
    "reef_ring": OKABE_ITO["blue"],
    "reef_cone": OKABE_ITO["vermillion"],
    "tetrapod_b": OKABE_ITO["green"],
    "tetrapod_s": OKABE_ITO["purple"],
}

GT_STYLE = {"color": OKABE_ITO["black"], "linestyle": "-", "marker": "s", "label": "ground truth"}

METHOD_STYLES = {
    "model_based_paper": {"color": OKABE_ITO["orange"], "linestyle": "--", "marker": "o"},
    "model_based_ours": {"color": OKABE_ITO["vermillion"], "linestyle": "--", "marker": "D"},
    "sasa_25": {"color": OKABE_ITO["sky_blue"], "linestyle": "-.", "marker": "v"},
    "sasa_50": {"color": OKABE_ITO["green"], "linestyle": "-.", "marker": "^"},
    "sasa_100": {"color": OKABE_ITO["blue"], "linestyle": ":", "marker": "P"},
}

_SPARE = [OKABE_ITO[k] for k in ("purple", "yellow", "orange", "sky_blue", "green", "blue")] + ["#777777"]

#: Point-cloud colour map (perceptually uniform, readable in grey and by colour-blind readers).
HEIGHT_CMAP = "viridis"

DPI = 120


def _stable_pick(name: str, options: list):
    # Deterministic across runs (Python's hash() is salted per process).
    h = int(hashlib.sha1(name.encode("utf-8")).hexdigest(), 16)
    return options[h % len(options)]


def class_color(cls: str) -> str:
    """Colour (hex) of an object class; unknown classes get a stable spare colour."""
    return CLASS_COLORS.get(cls) or _stable_pick(cls, _SPARE)


def method_family(method: str) -> str:
    """'model-based', 'SASA' or 'other', from a method id such as 'model_based_ours' or 'sasa_50'."""
    if method.startswith("model_based"):
        return "model-based"
    if method.startswith("sasa"):
        return "SASA"
    return "other"


def method_style(method: str) -> dict:
    """Colour, linestyle and marker of a method (fixed for the known methods, stable for others)."""
    if method in METHOD_STYLES:
        return dict(METHOD_STYLES[method])
    ls = {"model-based": "--", "SASA": "-."}.get(method_family(method), "-")
    return {"color": _stable_pick(method, _SPARE), "linestyle": ls, "marker": "X"}


def new_figure(width_in: float, height_in: float) -> Figure:
    """A pyplot-free figure of the given size (inches) with an Agg canvas attached."""
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def write_figure(fig: Figure, out_png, dpi: int = DPI) -> Path:
    """Write a figure as PNG atomically (no half-written file on error); returns the path."""
    out_png = Path(out_png)
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    return out_png
