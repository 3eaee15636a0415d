"""SASA (3DSSD + semantics-augmented set abstraction) detector in pure PyTorch, adapted to MBES scenes.

Layout as OpenPCDet: :mod:`.backbone` (PointNet++ SA layers with D-FPS / S-FPS), :mod:`.head` (3DSSD
vote head), :mod:`.box_coder` (symmetry-aware bin/residual coder), :mod:`.losses`, :mod:`.model` (the
detector, post-processing), :mod:`.data` (ground filter, sampling, augmentation), :mod:`.config`
(``DEFAULTS`` / ``STUDY`` hyper-parameters), :mod:`.trainer` (``train``, ``TrainedSASA`` (a saved model
loaded once, called per point cloud), ``infer``, ``infer_models`` (several models, each scene
prepared once)), :mod:`.ops` (point operators). Reference: blakechen97/SASA. The network modules
(torch) are imported on first use.
"""

from .config import DEFAULTS, PRESETS, STUDY, resolve_params

__all__ = ["DEFAULTS", "PRESETS", "STUDY", "resolve_params", "SASADetector", "TrainedSASA", "train", "infer",
           "infer_models", "detect_points", "read_model", "ConfigMismatchError"]

_LAZY = {"SASADetector": "model", "TrainedSASA": "trainer", "train": "trainer", "infer": "trainer",
         "infer_models": "trainer", "detect_points": "trainer", "read_model": "trainer",
         "ConfigMismatchError": "trainer"}


def __getattr__(name):
    # torch is imported on first use, so reading the parameters (config validation) stays cheap.
    if name in _LAZY:
        import importlib

        mod = importlib.import_module(f".{_LAZY[name]}", __name__)
        return getattr(mod, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
