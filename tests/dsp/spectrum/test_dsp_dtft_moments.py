"""The DTFT near a peak from Chebyshev moments (lidard.dsp.spectrum.dtft, issue 18) against the direct sum.

X(f) = sum_n x[n] exp(-j 2 pi f n / N) is evaluated here term by term (the definition); the moment
evaluator must give it, and its first two derivatives, to ~1e-12 of sum |x| everywhere the estimators
move (|delta| up to the reach its terms were chosen for), at whole and fractional start bins, for real
and complex ramps. A Chebyshev series cut too early, or a wrong Chebyshev-to-power map, fails here.
"""

from __future__ import annotations

from math import comb

import numpy as np
import pytest

from lidard.dsp.spectrum.dtft import _DtftNearBin, _moment_basis, _reach_of_terms, _terms_for


def _direct(x: np.ndarray, f: np.ndarray, n: int, deriv: int = 0) -> np.ndarray:
    t = np.arange(n)
    ph = np.exp(-2j * np.pi * f[:, None] * t / n)
    return np.sum(x * ph * (-2j * np.pi * t / n) ** deriv, axis=-1)


@pytest.mark.parametrize("n", [64, 512, 1000])
@pytest.mark.parametrize("reach", [0.5, 1.01, 1.76])
@pytest.mark.parametrize("kind", ["real", "complex"])
@pytest.mark.parametrize("on_bins", [True, False])
def test_moments_give_the_dtft_and_its_derivatives(n, reach, kind, on_bins):
    rng = np.random.default_rng(n + int(100 * reach))
    m = 40
    x = rng.standard_normal((m, n))
    if kind == "complex":
        x = x + 1j * rng.standard_normal((m, n))
    f0 = rng.integers(1, n // 2 - 1, m).astype(float)
    if not on_bins:
        f0 = f0 + rng.uniform(-0.5, 0.5, m)
    ev = _DtftNearBin(x, None, f0, _terms_for(reach))
    scale = np.sum(np.abs(x), axis=-1)
    for delta in (-reach, -0.37 * reach, 0.0, 0.61 * reach, reach):
        d = np.full(m, delta)
        got = ev.dtft(d)
        want = _direct(x, f0 + d, n)
        assert np.max(np.abs(got - want) / scale) < 2e-12
    # derivatives: X = exp(-j pi delta (n-1)/n) G(delta), so dX/ddelta = e (G' - j pi (n-1)/n G)
    d = rng.uniform(-reach, reach, m)
    g, g1, _ = ev.eval(d, derivs=2)
    e = np.exp(-1j * np.pi * d * (n - 1) / n)
    assert np.max(np.abs(e * (g1 - 1j * np.pi * (n - 1) / n * g) - _direct(x, f0 + d, n, 1)) / scale) < 1e-11


@pytest.mark.parametrize("n_terms", [19, 26, 34])
def test_chebyshev_map_reproduces_the_power_moments_it_keeps(n_terms):
    """s^p = 2^(1-p) sum' C(p, m) T_(p-2m)(s): exact (to rounding) wherever p < Q, and the dropped part of
    s^p beyond T_(Q-1) is below the Taylor term it multiplies."""
    n = 300
    basis, coef_map = _moment_basis(n, n_terms)
    q_terms = basis.shape[1]
    half = (n - 1) / 2
    s = (np.arange(n) - half) / half
    # the real part of the map applied to a real moment vector: column p of R is coef_map's block
    # divided by the Taylor coefficient; rebuild R from its definition instead and check T against s^p
    for p in range(n_terms):
        approx = sum((1.0 if q == 0 else 2.0) * comb(p, (p - q) // 2) / 2.0 ** p * basis[:, q]
                     for q in range(p % 2, min(p, q_terms - 1) + 1, 2))
        err = np.max(np.abs(approx - s ** p))
        if p < q_terms:
            assert err < 1e-13
        else:
            # what is dropped: sum over q >= Q of C(p, (p-q)/2) / 2^(p-1) (|T_q| <= 1)
            bound = sum(2.0 * comb(p, (p - q) // 2) / 2.0 ** p for q in range(q_terms, p + 1) if (p - q) % 2 == 0)
            assert err <= bound + 1e-13
            # and what it costs X: the Taylor coefficient times that, at the reach, is far below 1e-12
            a = np.pi * (n - 1) / n
            reach = _reach_of_terms(n_terms)
            assert (a * reach) ** p / np.prod(np.arange(1, p + 1, dtype=float)) * err < 1e-12


def test_fewer_columns_than_the_power_basis():
    """The point of the change: the ramps are read against fewer basis columns than Taylor terms."""
    basis, coef_map = _moment_basis(512, _terms_for(1.01))
    assert basis.shape[1] < _terms_for(1.01) - 4
    assert coef_map.shape == (2 * _terms_for(1.01), 2 * basis.shape[1])


@pytest.mark.parametrize("k", [0.3, 1.2, 57.4, 127.8])
def test_real_tone_energy_is_the_least_squares_fit_at_each_offset(k):
    """_real_tone_fit (the likelihood the default estimator climbs, with its sines turned by the offsets)
    against the energy of the best a cos(wn) + b sin(wn) from a plain least-squares solve."""
    from lidard.dsp.ranging.estimators import _real_tone_fit

    n = 256
    rng = np.random.default_rng(7)
    t = np.arange(n)
    x = 0.8 * np.cos(2 * np.pi * k * t / n + 1.1) + 0.3 * rng.standard_normal(n)
    f0 = np.array([np.rint(k)])
    ev = _DtftNearBin(x[None, :], None, f0, _terms_for(1.01))
    d = np.array([k - f0[0] + 0.07])
    offsets = np.array([-0.4, -1e-3, 0.0, 1e-3, 0.3])
    got = _real_tone_fit(ev, d, offsets)[:, 0]
    for o, j in zip(offsets, got):
        w = 2 * np.pi * (f0[0] + d[0] + o) / n
        a = np.stack([np.cos(w * t), np.sin(w * t)], axis=1)
        coef, *_ = np.linalg.lstsq(a, x, rcond=None)
        energy = float(np.dot(a @ coef, x))            # projection energy x' A (A'A)^-1 A' x
        assert j == pytest.approx(energy, rel=1e-10, abs=1e-9)
