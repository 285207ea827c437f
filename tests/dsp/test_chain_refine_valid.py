"""The chain refines only the valid detection slots (issue 18): same answers as refining every slot,
fewer estimator rows."""

import numpy as np

import lidard.dsp.chain as chain
from lidard.dsp.detect.cfar import CfarSettings
from lidard.dsp.ranging.estimators import estimate
from lidard.dsp.spectrum.rangefft import RangeFFT


def _ramps(seed=3, n_pix=40, n_avg=3, n=360):
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    f = rng.uniform(20, 150, (n_pix, 1, 1))
    amp = np.where(rng.random((n_pix, 1, 1)) < 0.5, 30.0, 0.0)  # half the pixels have no return
    return amp * np.cos(2 * np.pi * f * t / n + rng.uniform(0, 6, (n_pix, 1, 1))) + rng.normal(0, 1, (n_pix, n_avg, n))


def test_valid_slots_match_a_refinement_of_every_slot_and_empty_slots_are_skipped(monkeypatch):
    x = _ramps()
    rf = RangeFFT(x.shape[-1], 1.0, 1.0, window="hann")
    spec = rf(x)
    rows_seen = []
    real_estimate = chain.estimate_rows

    def counting(xs, rows, bins, **kw):
        rows_seen.append(np.asarray(bins).size)
        return real_estimate(xs, rows, bins, **kw)

    monkeypatch.setattr(chain, "estimate_rows", counting)
    cfar = CfarSettings(method="os", pfa=1e-6, max_detections=2, bin_range=(2, 170), window="hann")
    res = chain.detect_and_refine(spec, lambda idx: (x, idx, spec), cfar=cfar, estimator="newton", average_axis=1)
    det = res.detections
    assert 0 < det.valid.sum() < det.valid.size          # a mix of valid and empty slots
    # every slot of every average refined, the old way, then averaged over the averages
    idx = np.broadcast_to(np.where(det.valid, det.index, 1)[:, None, :], x.shape[:-1] + (2,))
    full = estimate(x, idx, method="newton", window="hann", spectrum=spec).mean(axis=1)
    np.testing.assert_allclose(res.frac_bins[det.valid], full[det.valid], rtol=0, atol=1e-9)
    # the estimator saw only the valid slots (x the averages), not every slot
    assert rows_seen == [int(det.valid.sum()) * x.shape[1]]


def test_estimate_rows_reads_the_rows_in_place_with_the_same_answers():
    from lidard.dsp.ranging.estimators import ESTIMATOR_NAMES, estimate_rows
    from lidard.dsp.spectrum.window import DspInputError
    import pytest

    x = _ramps(n_pix=30, n_avg=1)[:, 0]
    rf = RangeFFT(x.shape[-1], 1.0, 1.0, window="hann")
    spec = rf(x)
    p = spec.real ** 2 + spec.imag ** 2
    rows = np.array([3, 0, 7, 7, 21, 29])
    bins = np.argmax(p[rows, 5:170], axis=-1) + 5
    for m in ESTIMATOR_NAMES:
        want = estimate(x[rows], bins, method=m, window="hann", spectrum=spec[rows])
        np.testing.assert_array_equal(estimate_rows(x, rows, bins, method=m, window="hann", spectrum=spec), want)
    bad = x.copy()
    bad[7, 11] = np.nan
    with pytest.raises(DspInputError, match="NaN"):
        estimate_rows(bad, rows, bins, method="newton", window="hann", spectrum=spec)
