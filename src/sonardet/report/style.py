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

from .. import methods
from ..io.atomic import atomic_path
from ..objects import classes

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

GT_STYLE = {"color": OKABE_ITO["black"], "linestyle": "-", "marker": "s", "label": "ground truth"}

_SPARE = [OKABE_ITO[k] for k in ("purple", "yellow", "orange", "sky_blue", "green", "blue")] + ["#777777"]

#: Point-cloud colour map (perceptually uniform, readable in grey and by colour-blind readers).
HEIGHT_CMAP = "viridis"

DPI = 120


def _stable_pick(name: str, options: list):
    # Deterministic across runs (Python's hash() is salted per process).
    h = int(hashlib.sha1(name.encode("utf-8")).hexdigest(), 16)
    return options[h % len(options)]


def class_color(cls: str) -> str:
    """Colour (hex) of an object class: its spec's (sonardet.objects.classes); an unregistered class
    gets a stable spare colour."""
    return classes.get(cls).colour if cls in classes.names() else _stable_pick(cls, _SPARE)


def _family_of(method: str):
    """The registered family whose name prefix a method's name has (the longest one; None if none)."""
    fams = [f for f in methods.families() if method == f.name or (f.prefix and method.startswith(f.prefix))]
    return max(fams, key=lambda f: len(f.prefix)) if fams else None


def method_family(method: str) -> str:
    """The report label of a method's family ('model-based', 'SASA', ...), 'other' if unknown."""
    fam = _family_of(method)
    return fam.label if fam is not None else "other"


_FAMILY_LINESTYLES = {"model-based": "--", "SASA": "-."}


def method_style(method: str) -> dict:
    """Colour, linestyle and marker of a method (its family's fixed style for the known methods,
    a stable spare colour otherwise)."""
    fam = _family_of(method)
    if fam is not None and method in fam.styles:
        return dict(fam.styles[method])
    ls = _FAMILY_LINESTYLES.get(method_family(method), "-")
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
