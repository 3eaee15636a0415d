"""The shadow test of the model-based scoring: template points hidden under observed points are not asked
for (sonardet.detect.model_based.scoring.ShadowMap)."""

import numpy as np

from sonardet.detect.model_based.scoring import ShadowMap, _excused


def _slab(x0, x1, y0, y1, z, step=0.05):
    g = np.mgrid[x0:x1:step, y0:y1:step].reshape(2, -1).T
    return np.c_[g, np.full(len(g), z)]


def test_points_under_an_observed_overhang_are_shadowed():
    # seabed at z=0 over 2 x 2 m, a plank observed at z=1 over x in [0.5, 1.0]
    scene = np.vstack([_slab(0, 2, 0, 2, 0.0), _slab(0.5, 1.0, 0, 2, 1.0)])
    sm = ShadowMap(scene, cell_m=0.15, margin_m=0.2)
    q = np.array([[0.75, 1.0, 0.5],    # under the plank: shadowed
                  [0.75, 1.0, 0.9],    # just under it, within the margin: not
                  [1.6, 1.0, 0.5],     # in the open: not
                  [0.75, 1.0, 1.5],    # above it: not
                  [5.0, 5.0, -1.0]])   # outside the map: not
    assert sm.shadowed(q).tolist() == [True, False, False, False, False]
    # next to the plank's edge: the 8-neighbourhood reaches one cell beyond it
    assert sm.shadowed(np.array([[1.1, 1.0, 0.5]]))[0]
    assert not sm.shadowed(np.array([[1.4, 1.0, 0.5]]))[0]


def test_hit_points_are_never_excused():
    scene = np.vstack([_slab(0, 2, 0, 2, 0.0), _slab(0.5, 1.0, 0, 2, 1.0)])
    sm = ShadowMap(scene, cell_m=0.15, margin_m=0.2)
    q = np.array([[0.75, 1.0, 0.5], [0.75, 1.2, 0.5], [1.6, 1.0, 0.5]])
    hit = np.array([True, False, False])
    assert _excused(q, hit, sm).tolist() == [False, True, False]
    assert not _excused(q, hit, None).any()
