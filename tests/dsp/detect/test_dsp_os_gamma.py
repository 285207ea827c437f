"""OS-CFAR on averaged spectra: the false-alarm rate of Gamma(K) noise cells (lidard.dsp.detect.os_gamma)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidard.dsp.chain import detect_and_refine
from lidard.dsp.detect.cfar import CfarSettings, DspInputError, cfar_detect_with
from lidard.dsp.detect.os_cfar import _noise_os, os_cfar_alpha, os_cfar_pfa
from lidard.dsp.detect.os_gamma import log_tails, os_gamma_mean_kth, os_gamma_pfa

N_REF, RANK = 16, 12


@pytest.mark.parametrize("alpha", [0.05, 0.7, 3.0, 12.0, 40.0, 150.0])
def test_quadrature_at_one_record_is_rohlings_closed_form(alpha: float) -> None:
    i = np.arange(RANK)
    closed = float(np.prod((N_REF - i) / (N_REF - i + alpha)))
    assert os_gamma_pfa(alpha, N_REF, RANK, 1) == pytest.approx(closed, rel=1e-12)
    assert os_cfar_pfa(alpha, N_REF, RANK, 1) == closed            # K = 1 is the closed form itself


def test_mean_kth_at_one_record_is_the_harmonic_sum() -> None:
    from lidard.dsp.detect import os_gamma
    z, w = os_gamma._order_statistic(N_REF, RANK, 1)
    harmonic = sum(1.0 / j for j in range(N_REF - RANK + 1, N_REF + 1))
    assert float(np.dot(w, z)) == pytest.approx(harmonic, rel=1e-12)


@pytest.mark.parametrize("records", [1, 3, 10, 60])
def test_log_tails_sum_to_one_and_match_the_finite_sum(records: int) -> None:
    t = np.array([1e-3, 0.3, 0.9, 1.0, 2.5, records * 0.5, records - 1e-9, records, records * 1.7, 4.0 * records + 20])
    log_p, log_q = log_tails(t, records)
    np.testing.assert_allclose(np.exp(log_p) + np.exp(log_q), 1.0, rtol=1e-12)
    direct = np.array([math.exp(-x) * sum(x ** j / math.factorial(j) for j in range(records)) for x in t])
    np.testing.assert_allclose(np.exp(log_q), direct, rtol=1e-10)
    # deep in the lower tail P(K, t) ~ t^K / K!
    small = np.array([1e-6])
    assert math.exp(log_tails(small, records)[0][0]) == pytest.approx(1e-6 ** records / math.factorial(records), rel=1e-5)


@pytest.mark.parametrize("records", [4, 10])
def test_rate_matches_monte_carlo_and_rohlings_factor_undershoots(records: int) -> None:
    """Cells averaged over K records (Gamma(K)): the K-model's alpha alarms at the stated rate within a
    5-sigma binomial bound; the exponential model's alpha alarms far below it (the defect it fixes)."""
    pfa, n = 1e-3, 1_000_000
    rng = np.random.default_rng(20261127 + records)
    cells = rng.gamma(records, 1.0 / records, size=(n, N_REF + 1))
    x, ref = cells[:, 0], cells[:, 1:]
    kth = np.partition(ref, RANK - 1, axis=1)[:, RANK - 1]
    alpha_k = os_cfar_alpha(N_REF, RANK, pfa, records)
    hits = int(np.count_nonzero(x > alpha_k * kth))
    assert abs(hits - n * pfa) < 5 * math.sqrt(n * pfa * (1 - pfa))
    stale = int(np.count_nonzero(x > os_cfar_alpha(N_REF, RANK, pfa) * kth))
    assert stale < 0.2 * n * pfa
    # the noise-mean scale: E[k-th of N unit-mean Gamma(K) cells]
    assert abs(kth.mean() - os_gamma_mean_kth(N_REF, RANK, records)) < 5 * kth.std() / math.sqrt(n)


def test_alpha_solves_the_rate_and_falls_with_records() -> None:
    alphas = [os_cfar_alpha(N_REF, RANK, 1e-6, k) for k in (1, 2, 4, 10, 100)]
    for k, a in zip((1, 2, 4, 10, 100), alphas):
        assert os_cfar_pfa(a, N_REF, RANK, k) == pytest.approx(1e-6, rel=1e-9)
    assert all(b < a for a, b in zip(alphas, alphas[1:]))
    # many records: the averaged noise is nearly constant, the threshold tends to the k-th's mean
    assert alphas[-1] * os_gamma_mean_kth(N_REF, RANK, 100) < 2.5


def test_dense_os_noise_alarms_at_the_stated_rate_on_averaged_cells() -> None:
    """Through the detector's OS statistic (mirrored edges, guard cells) on independent Gamma(K) cells."""
    records, pfa = 8, 1e-3
    rng = np.random.default_rng(7)
    p = rng.gamma(records, 1.0 / records, size=(400, 2048))
    noise, thr = _noise_os(p, N_REF // 2, 2, pfa, None, exact=True, records=records)
    hits = int(np.count_nonzero(p > thr * noise))
    assert abs(hits - p.size * pfa) < 5 * math.sqrt(p.size * pfa)
    # the noise estimate is the mean noise power (1 here), not the k-th's scale
    assert abs(np.median(noise) - 1.0) < 0.05


def test_chain_takes_the_records_from_the_averaged_axis() -> None:
    rng = np.random.default_rng(3)
    spec = (rng.standard_normal((50, 6, 257)) + 1j * rng.standard_normal((50, 6, 257))) / math.sqrt(2)
    spec[:, :, 100] += 1.6     # a weak line: detected on the averaged spectrum only at the K-model's threshold
    cfar = CfarSettings(pfa=1e-4, max_detections=3)
    res = detect_and_refine(spec, lambda idx: (spec, idx.astype(float), None), cfar=cfar, estimator="parabolic",
                            average_axis=1)
    p = (np.abs(spec) ** 2).mean(axis=1)
    want = cfar_detect_with(p, CfarSettings(pfa=1e-4, max_detections=3, records=6))
    np.testing.assert_array_equal(res.detections.index, want.index)
    stale = cfar_detect_with(p, cfar)
    assert (want.index == 100).sum() > (stale.index == 100).sum()
    with pytest.raises(DspInputError, match="records"):
        detect_and_refine(spec, lambda idx: (spec, idx.astype(float), None), cfar=CfarSettings(records=6),
                          estimator="parabolic", average_axis=1)


@pytest.mark.parametrize("bad", [0, -2, 2.5, True])
def test_bad_records_is_refused(bad: object) -> None:
    with pytest.raises(DspInputError, match="records"):
        cfar_detect_with(np.ones((1, 64)), CfarSettings(records=bad))  # type: ignore[arg-type]


def test_screens_and_compiled_pass_decide_as_the_dense_averaged_threshold(monkeypatch) -> None:
    """The sparse screens (numpy and, with numba, compiled) take the Gamma(K) constants too: their
    detections are exactly the local maxima over the dense exact threshold of the same model."""
    from lidard.dsp.spectrum import jit
    records = 8
    rng = np.random.default_rng(11)
    p = rng.gamma(records, 1.0 / records, size=(200, 512))
    p[:, 100] += np.linspace(0.5, 6.0, 200)     # lines from below to above the K = 8 threshold
    noise, thr = _noise_os(p, N_REF // 2, 2, 1e-4, None, exact=True, records=records)
    peak = np.ones(p.shape, bool)
    peak[:, 1:] &= p[:, 1:] >= p[:, :-1]
    peak[:, :-1] &= p[:, :-1] > p[:, 1:]
    want = np.nonzero(peak & (p > thr * noise))
    assert want[0].size > 100
    kerns = [None] + ([jit.kernels()] if jit.kernels() is not None else [])
    for kern in kerns:
        if kern is None:
            monkeypatch.setenv("LIDARD_DSP_JIT", "0")
        from lidard.dsp.detect.os_cfar import _os_detected
        found = _os_detected(p, N_REF // 2, 2, 1e-4, None, 1e-20, kern, records)
        assert found is not None
        np.testing.assert_array_equal(found[0], want[0])
        np.testing.assert_array_equal(found[1], want[1])
        np.testing.assert_allclose(found[2], noise[want], rtol=1e-12)
        monkeypatch.delenv("LIDARD_DSP_JIT", raising=False)
