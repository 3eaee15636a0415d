"""Tests of sonardet.sim.rocks: irregular convex rocks."""

import numpy as np
import pytest
from scipy.spatial import ConvexHull

from sonardet.sim.rocks import ROCK_SIZE_RANGE_M, make_rock, make_rocks, rock_mass_kg


@pytest.mark.parametrize("size", [0.2, 0.45, 1.0, 1.5])
def test_rock_convex_watertight_and_sized(size):
    rng = np.random.default_rng(int(size * 100))
    for _ in range(5):
        m = make_rock(size, rng)
        assert m.is_watertight and m.is_volume and m.is_convex
        assert float(np.max(m.extents)) == pytest.approx(size, rel=1e-9)
        assert m.volume > 0
        # its own single convex part: the hull of its vertices is itself
        assert ConvexHull(m.vertices).volume == pytest.approx(m.volume, rel=1e-9)
        # canonical frame: base centre at the origin, z up
        lo, hi = m.bounds
        assert lo[2] == pytest.approx(0.0, abs=1e-12)
        assert np.allclose(0.5 * (lo[:2] + hi[:2]), 0.0, atol=1e-12)
        # squashed: flatter than wide (flatness 0.35-0.75 before jitter)
        assert m.extents[2] < m.extents[:2].max()


def test_rocks_are_irregular_and_deterministic():
    a = make_rocks(6, np.random.default_rng(4))
    b = make_rocks(6, np.random.default_rng(4))
    for ra, rb in zip(a, b):
        assert np.array_equal(ra.vertices, rb.vertices) and np.array_equal(ra.faces, rb.faces)
    # different rocks differ in shape, not only in scale
    shapes = [tuple(np.round(r.extents / r.extents.max(), 3)) for r in a]
    assert len(set(shapes)) == len(shapes)
    sizes = [float(r.extents.max()) for r in a]
    assert all(ROCK_SIZE_RANGE_M[0] <= s <= ROCK_SIZE_RANGE_M[1] + 1e-12 for s in sizes)


def test_make_rocks_size_range_log_uniform():
    rocks = make_rocks(200, np.random.default_rng(0), size_range_m=(0.2, 1.5))
    s = np.array([r.extents.max() for r in rocks])
    assert s.min() >= 0.2 - 1e-9 and s.max() <= 1.5 + 1e-9
    assert np.median(s) < 0.7  # log-uniform median sqrt(0.2*1.5) = 0.55


def test_rock_mass():
    m = make_rock(1.0, np.random.default_rng(1))
    assert rock_mass_kg(m) == pytest.approx(m.volume * 2650.0)
    assert rock_mass_kg(m, 2000.0) == pytest.approx(m.volume * 2000.0)


def test_rock_size_out_of_range_rejected():
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError):
        make_rock(0.1, rng)
    with pytest.raises(ValueError):
        make_rock(2.0, rng)
    with pytest.raises(ValueError):
        make_rocks(3, rng, size_range_m=(0.1, 1.0))
