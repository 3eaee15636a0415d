"""The survey benchmark's object placement (benchmarks/detect_jobs.py `place_objects`): gaps honoured,
an impossible request refused with the option to change."""

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from detect_jobs import place_objects


def test_objects_keep_their_gap():
    rng = np.random.default_rng(0)
    radii = rng.uniform(0.7, 1.4, 120)
    c = place_objects(radii, 60.0, 0.5, rng)
    assert c.shape == (120, 2)
    assert np.all((c >= 3.0) & (c <= 57.0))
    d = np.hypot(*(c[:, None, :] - c[None, :, :]).transpose(2, 0, 1))
    need = radii[:, None] + radii[None, :] + 0.5
    np.fill_diagonal(d, np.inf)
    assert np.all(d >= need)


def test_same_seed_same_layout():
    radii = np.full(30, 1.0)
    a = place_objects(radii, 40.0, 0.5, np.random.default_rng(4))
    b = place_objects(radii, 40.0, 0.5, np.random.default_rng(4))
    assert np.array_equal(a, b)


def test_too_many_objects_are_refused():
    with pytest.raises(ValueError, match="--objects 200"):
        place_objects(np.full(200, 1.4), 20.0, 0.5, np.random.default_rng(0))
