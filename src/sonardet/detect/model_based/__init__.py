"""Model-based (training-free) detection: seabed removal, segmentation, template/mesh registration,
scoring and duplicate removal. Entry points: :class:`ModelBasedDetector` (built once, called per point
cloud) and :func:`detect` (one cloud); hyper-parameters: `DEFAULTS` (variant 'ours') and `PAPER`
(variant 'paper').

The detector (Open3D) is imported on first use, so reading the parameters (e.g. to validate a
workflow config) stays cheap.
"""

from .params import DEFAULTS, DESCRIPTIONS, PAPER, VARIANTS, resolve_params

__all__ = ["DEFAULTS", "DESCRIPTIONS", "PAPER", "VARIANTS", "ModelBasedDetector", "class_models", "detect",
           "new_stats", "resolve_params"]


def __getattr__(name):
    if name in ("ModelBasedDetector", "class_models", "detect", "new_stats"):
        from . import detector

        return getattr(detector, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
