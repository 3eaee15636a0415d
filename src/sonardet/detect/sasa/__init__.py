"""SASA (3DSSD + semantics-augmented set abstraction) detector in pure PyTorch, adapted to MBES scenes.

Layout as OpenPCDet: :mod:`.backbone` (PointNet++ SA layers with D-FPS / S-FPS), :mod:`.head` (3DSSD
vote head), :mod:`.box_coder` (symmetry-aware bin/residual coder), :mod:`.losses`, :mod:`.model` (the
detector, post-processing), :mod:`.data` (ground filter, sampling, augmentation), :mod:`.config`
(``DEFAULTS`` / ``PAPER`` hyper-parameters), :mod:`.train` (``train`` / ``infer``), :mod:`.ops` (point
operators). Reference: blakechen97/SASA.
"""

from .config import DEFAULTS, PAPER, resolve_params
from .model import SASADetector
from .train import ConfigMismatchError, detect_points, infer, load_model, train

__all__ = ["DEFAULTS", "PAPER", "resolve_params", "SASADetector", "train", "infer", "detect_points", "load_model",
           "ConfigMismatchError"]
