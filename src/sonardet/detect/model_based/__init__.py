"""Model-based (training-free) detection: seabed removal, segmentation, template/mesh registration,
scoring and duplicate removal. Entry point: :func:`detect`; hyper-parameters: `DEFAULTS` (variant
'ours') and `PAPER` (variant 'paper')."""

from .detector import class_models, detect, new_stats
from .params import DEFAULTS, DESCRIPTIONS, PAPER, resolve_params

__all__ = ["DEFAULTS", "DESCRIPTIONS", "PAPER", "class_models", "detect", "new_stats", "resolve_params"]
