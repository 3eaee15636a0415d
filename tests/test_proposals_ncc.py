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


def _peaks_reference(best, occ_frac, ncc_min, occ_min, nms_radius_cells):
    """ncc_peaks with SciPy's maximum filter over the whole raster."""
    from scipy import ndimage as ndi

    size = 2 * max(1, int(nms_radius_cells)) + 1
    mx = ndi.maximum_filter(best, size=size, mode="constant", cval=-1.0)
    i, j = np.nonzero((best >= mx) & (best >= ncc_min) & (occ_frac >= occ_min))
    order = np.argsort(-best[i, j], kind="stable")
    return i[order], j[order]


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_ncc_peaks_equal_the_maximum_filter(dtype):
    """The peaks looked for around the cells that pass the minima only are those of the maximum filter
    over the whole raster: ties (plateaus), peaks at the border, values below -1 beyond which the
    filter's padding lies, radii 0 (taken as 1) to 6."""
    from sonardet.detect.model_based.proposals import ncc_peaks

    rng = np.random.default_rng(6)
    n_peaks = 0
    for trial in range(12):
        best = rng.uniform(-1.2, 1.0, (61, 47)).astype(dtype)
        best[rng.random(best.shape) < 0.3] = 0.7  # ties: plateaus of equal values
        best[:, :3] = np.round(best[:, :3], 1)  # more ties at the border
        if trial % 3 == 0:
            best[:] = -1.1  # everything below the padding: no peak at the border
            best[30, 20] = -1.05
        occ = rng.uniform(0.0, 1.0, best.shape).astype(np.float32)
        for r in (0, 1, 3, 6):
            for ncc_min, occ_min in ((-2.0, 0.0), (0.2, 0.3), (0.5, 0.0)):
                got = ncc_peaks(best, occ, ncc_min, occ_min, r)
                want = _peaks_reference(best, occ, ncc_min, occ_min, r)
                np.testing.assert_array_equal(got[0], want[0])
                np.testing.assert_array_equal(got[1], want[1])
                n_peaks += len(got[0])
    assert n_peaks > 100  # a check that can fail
