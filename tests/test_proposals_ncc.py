"""The NCC proposal maps and the vote maps reuse each raster's and kernel's spectrum
(proposals.Correlator), also when one correlator serves every class of a round: their outputs must
equal, to the bit, the same maps computed with one scipy fftconvolve per pair (`_corr`)."""

import numpy as np
import pytest
from scipy.signal import fftconvolve

from sonardet.detect.model_based.proposals import (
    Correlator,
    Kernel,
    Raster,
    ncc_maps,
    ncc_rasters,
    vote_map,
)


def _corr(a: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Correlation of raster a with kernel k ('same' size, float32) by scipy's fftconvolve."""
    return fftconvolve(a.astype(np.float32, copy=False), k[::-1, ::-1].astype(np.float32), mode="same")


def _reference(r, kernels, occupied_min_m, min_data_frac):
    """ncc_maps as written with one scipy fftconvolve per correlation."""
    d, f, occ = ncc_rasters(r, occupied_min_m)
    best, arg, occ_frac = np.full(r.h.shape, -1.0), np.zeros(r.h.shape, dtype=np.int64), None
    for k, ker in enumerate(kernels):
        m = ker.support
        n = np.maximum(_corr(d, m), 1.0)
        sf, sff, occ_frac = _corr(f, m), _corr(f * f, m), _corr(occ, m) / n
        t = ker.height
        st, stt, sft = _corr(d, t), _corr(d, t * t), _corr(f, t)
        num = sft - sf * st / n
        den = np.sqrt(np.clip((sff - sf * sf / n) * (stt - st * st / n), 1e-12, None))
        ncc = np.where(n >= min_data_frac * m.sum(), num / den, -1.0)
        better = ncc > best
        best[better] = ncc[better]
        arg[better] = k
    return best, arg, occ_frac


def _kernels(rng, size, n):
    c = np.arange(size) - size // 2
    gx, gy = np.meshgrid(c, c)
    support = (np.hypot(gx, gy) <= size // 2).astype(np.float64)
    return [Kernel(float(y), rng.uniform(0.0, 2.0, (size, size)) * support, support)
            for y in np.linspace(0, 1, n)]


def test_ncc_maps_equal_the_per_pair_fftconvolve_to_the_bit():
    rng = np.random.default_rng(3)
    h = rng.uniform(-0.1, 2.0, (157, 203))
    h[rng.random(h.shape) < 0.2] = np.nan  # shadow and hidden cells
    r = Raster(h, 0.0, 0.0, 0.1)
    for size, n in ((29, 4), (41, 1)):
        kernels = _kernels(rng, size, n)
        got = ncc_maps(r, kernels, 0.15, 0.5)
        want = _reference(r, kernels, 0.15, 0.5)
        for g, w in zip(got, want):
            assert g.dtype == w.dtype and g.shape == w.shape
            assert np.array_equal(g, w)
        assert (got[0] > -1).any() and len(set(got[1].ravel())) == n  # a check that can fail
        # The kernels keep their spectra for the next raster: of the same shape (a scene's next
        # round) and of another shape (the next tile), the outputs still equal the reference.
        for shape in ((157, 203), (120, 90)):
            h2 = rng.uniform(-0.1, 2.0, shape)
            h2[rng.random(shape) < 0.3] = np.nan
            r2 = Raster(h2, 0.0, 0.0, 0.1)
            for g, w in zip(ncc_maps(r2, kernels, 0.15, 0.5), _reference(r2, kernels, 0.15, 0.5)):
                assert np.array_equal(g, w)


def test_vote_maps_equal_the_per_pair_fftconvolve_to_the_bit():
    rng = np.random.default_rng(4)
    h = rng.uniform(-0.1, 2.0, (131, 177))
    h[rng.random(h.shape) < 0.2] = np.nan
    r = Raster(h, 0.0, 0.0, 0.1)
    for size, n in ((29, 4), (41, 2)):
        kernels = _kernels(rng, size, n)
        best, arg = vote_map(r, kernels, 0.15)
        occ = (np.nan_to_num(h, nan=0.0) > 0.15).astype(np.float64)
        want_best, want_arg = np.full(h.shape, -1.0), np.zeros(h.shape, dtype=np.int64)
        for k, ker in enumerate(kernels):
            fp = (ker.height > 0.15).astype(np.float64)
            v = _corr(occ, fp) / max(fp.sum(), 1.0)
            better = v > want_best
            want_best[better], want_arg[better] = v[better], k
        assert np.array_equal(best, want_best) and np.array_equal(arg, want_arg)
        assert len(set(arg.ravel())) > 1  # the kernels compete: a check that can fail


def test_one_correlator_for_every_class_of_a_round_gives_the_same_maps():
    """The classes of a round share one Correlator (the raster's spectra computed once, for kernels of
    different sizes): each class's NCC and vote maps equal those of its own correlator, to the bit;
    a correlator refuses another raster."""
    rng = np.random.default_rng(5)
    h = rng.uniform(-0.1, 2.0, (140, 160))
    h[rng.random(h.shape) < 0.2] = np.nan
    r = Raster(h, 0.0, 0.0, 0.1)
    classes = [_kernels(rng, 23, 3), _kernels(rng, 31, 1), _kernels(rng, 33, 2)]
    shared = Correlator(r)
    for kernels in classes:
        for g, w in zip(ncc_maps(r, kernels, 0.15, 0.5, shared), _reference(r, kernels, 0.15, 0.5)):
            assert np.array_equal(g, w)
        for g, w in zip(vote_map(r, kernels, 0.15, shared), vote_map(r, kernels, 0.15)):
            assert np.array_equal(g, w)
    # The spectra a round computes first are exactly those the maps asked for.
    needed = shared.raster_spectra_needed([k[0].support.shape for k in classes], votes=True)
    assert {(n, shared._fshape(ks)[1], 0.15) for n, ks in needed} == set(shared._spectra)
    with pytest.raises(ValueError, match="another raster"):
        ncc_maps(Raster(h.copy(), 0.0, 0.0, 0.1), classes[0], 0.15, 0.5, shared)
