"""The chain refines only the valid detection slots (issue 18): same answers as refining every slot,
fewer estimator rows."""

import numpy as np

import lidard.dsp.chain as chain
from lidard.dsp.estimators import estimate
from lidard.dsp.rangefft import RangeFFT


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
    real_estimate = chain.estimate

    def counting(xs, bins, **kw):
        rows_seen.append(np.asarray(bins).size)
        return real_estimate(xs, bins, **kw)

    monkeypatch.setattr(chain, "estimate", counting)
    res = chain.detect_and_refine(spec, lambda idx: (x, idx, spec), window="hann", estimator="newton",
                                  average_axis=1, method="os", pfa=1e-6, max_detections=2, bin_range=(2, 170))
    det = res.detections
    assert 0 < det.valid.sum() < det.valid.size          # a mix of valid and empty slots
    # every slot of every average refined, the old way, then averaged over the averages
    idx = np.broadcast_to(np.where(det.valid, det.index, 1)[:, None, :], x.shape[:-1] + (2,))
    full = estimate(x, idx, method="newton", window="hann", spectrum=spec).mean(axis=1)
    np.testing.assert_allclose(res.frac_bins[det.valid], full[det.valid], rtol=0, atol=1e-9)
    # the estimator saw only the valid slots (x the averages), not every slot
    assert rows_seen == [int(det.valid.sum()) * x.shape[1]]
