"""Line-to-line vertical offsets (stage ``point``): every sounding of a survey line moves by the
line's N(0, sigma^2) offset (tide, draft and heave-filter residuals).

Point-stage form: :func:`line_offsets_m` (one offset per line) and :func:`line_offset_dz`.
"""

from __future__ import annotations

import numpy as np

from .base import OFFSET, Effect, Key, ScanChunk, ScanSetup, non_negative


def line_offsets_m(sigma_m: float, normal: np.ndarray) -> np.ndarray:
    """Vertical offset (m, + up) of each line: sigma_m times its standard normal draw `normal` (L,)."""
    return sigma_m * normal


def line_offset_dz(offsets_m: np.ndarray, line_row: np.ndarray) -> np.ndarray:
    """Elevation change (m) of soundings of the lines `line_row` (indices into offsets_m (L,))."""
    return offsets_m[line_row]


def _setup(cfg, setup: ScanSetup) -> None:
    setup.values["line_offsets"] = line_offsets_m(cfg.line_offset_sigma_m, setup.lines.normal[:, OFFSET])


def _apply(cfg, setup: ScanSetup, chunk: ScanChunk, rng: np.random.Generator) -> None:
    dz = line_offset_dz(setup.values["line_offsets"], chunk.line_row)
    chunk.add_dz(np.broadcast_to(dz[:, None], chunk.r.shape))


LINE_OFFSETS = Effect(
    name="line_offsets", stage="point", order=80, doc=__doc__,
    keys=(Key("line_offset_sigma_m", 0.0, "m", "std of a random vertical offset per survey line (m)",
              {"$ref": "#/definitions/nonneg"}, (non_negative,)),),
    switches=("line_offset_sigma_m",), setup=_setup, apply=_apply,
)
