"""Range linearity over 0.8-45 m: plates read on one straight line (scale + offset) within 0.1 mm.

A nominal bench (no hidden tolerances) without the laser's phase noise, so what is left is the
instrument's deterministic range error: each plate measured through the instrument as the range
calibration measures it (centre pixels, the scan's DSP), after one linearization. A range scale that
changes with distance (the chirp's residual slope inside the range estimator's window, which the beat
averages over its round trip) shows as a departure from the best line; with the learned chirp's
turnaround transient inside the window it was 0.6 mm at 45 m (docs/measured/26_range_linearity.md).

Two asserts: the four plates within 0.1 mm of their best line (the specification), and the
departures consistent, at the 99.9 % level, with what is known to move them: each measurement's own
standard error ``s_i`` (``sem_m``, its pixels' spread) and one term they all share, the chirp error
the linearization leaves.

**The linearization's residual.** The learned chirp is ``nu(t) = kappa t + dnu(t)``. The linearization
reports the RMS of ``dnu`` over the range window for each ramp (the error against the ideal chirp,
offset free, of the drive it kept: ``iterations[meta["best_iteration"]]`` ``up_error_hz`` /
``down_error_hz``, 39 kHz here) and the bandwidth it learns in, ``B`` (``meta["learning_bandwidth_hz"]``,
the Q filter's 1 MHz: the drive corrects nothing finer). Its noise floor is 17 Hz: the residual is what
the learning stopped improving on (mostly the turnaround's tail at the window's edges), not noise, and
it is the same for every noise draw; what is unknown is its shape. The model: ``dnu`` a stationary
random function of RMS ``sigma = (sigma_up + sigma_down) / 2`` with a flat spectrum to ``B`` (PSD
``sigma^2 / 2B``), the same on both ramps (the same turnaround at both ends: they add, not average).

**Through the range estimator.** A plate at round trip ``tau = 2 d / c`` beats at ``kappa tau + dnu(t)
- dnu(t - tau)``. The estimator (``newton``: least-squares sinusoid on the raw samples of the window,
uniform weights, ``2a = 0.9 x 80 us``) reads the phase's least-squares slope, i.e. the instantaneous
beat weighted by ``g(s) = 3 (a^2 - s^2) / (4 a^3)`` on ``|s| <= a``, whose Fourier transform is ``G(f) =
3 (sin x - x cos x) / x^3``, ``x = 2 pi f a``. The range is ``c f / (2 kappa)`` averaged over the ramps,
so the measurements' errors from ``dnu`` have the covariance

    C_lin[i, j] = (c / 2 kappa)^2 (sigma^2 / B) int_0^B |G(f)|^2 Re[H_i(f) conj(H_j(f))] df,
    H_i(f) = 1 - exp(-2j pi f tau_i)   (0 for a compensated measurement, below)

For ``tau << a`` this is ``d_i d_j sigma_eps^2``, ``sigma_eps = (sigma / kappa) sqrt(3 / (4 B a^3))``
= 1.5e-6: to first order a residual chirp error is a slope error, a range scale error common to the
plates. The sim's laser model under the learned drive (ground truth) gives a slope error of +1.5e-6
over the window on every seed tried (1-3), and through the estimator's weight 1, 8, 37 um at 0.8, 5,
20 m (96 um at 45 m) on the plain front end; the plates read that within their noise. The 20 m plate,
about 3 standard errors off a line through the others, is why the chi-square without this term passed
or failed with the noise draw (14.0 and 14.6 > 13.8 on one draw; 22 % of simulated draws).

A common scale would be absorbed by the line, but not every plate goes through the same front end. At
``max_range_m >= c tau_m`` (the 45 m plate) the scan compensates the laser's phase from the quadrature
monitor (``phase_noise_compensation = "auto"``), which takes the chirp's error out at every delay and
ties the range scale to the monitor delay: a compensated measurement has no ``dnu`` term (measured:
-7..+7 um at 10-50 m, standard errors 5-23 um, where the plain front end read 13-71 um). The 45 m plate
is therefore measured twice, as the calibration does (compensated) and through the plain front end:
the pair ties the two front ends together, and the plain one extends the plain plates' line to 45 m,
so a range nonlinearity there cannot hide in the front ends' scale difference (with the four plates
alone the 45 m plate would be free by ``45 m x sigma_eps`` = 68 um). The chi-square is the full one,

    chi2 = r' C^-1 r,  C = diag(s_i^2) + C_lin,  r = e - A theta,  theta = (A' C^-1 A)^-1 A' C^-1 e,

``A = [1, d]``, ``n - 2`` = 3 degrees of freedom (``C_lin`` is a variance, not a fitted parameter).
What it still fails on (``test_chi2_passes_this_bench_and_fails_a_far_nonlinearity``): a range error
quadratic in ``d``, +-0.2 mm at 45 m, on this bench's pattern (chi-square 35 / 26 against 16.3; 2.0
without it). Put into every point of the scans (range + A (range / 45 m)^2, seed 1) it read 56.1 / 16.9
for A = +0.2 / -0.2 mm (and a 0.115 mm departure), 23.8 / 5.4 for +0.1 / -0.1 mm: 0.1 mm at 45 m (4.5
standard errors of that plate) is at the plates' resolution, about a third of noise draws catch it.
"""

from __future__ import annotations

import dataclasses
import threading

import numpy as np
import pytest
from scipy.special import gammaincinv

from lidard.config import load_config
from lidard.dsp.frame import RANGE_WINDOW_FRACTION
from lidard.instrument import open_instrument
from lidard.instrument.calibration.procedures import measure_plate
from lidard.instrument.calibration.range import plate_measurement, plate_request, plate_scene
from lidard.physics.constants import C_M_PER_S

PLATES_M = (0.8, 5.0, 20.0, 45.0)
MAX_DEPARTURE_M = 0.1e-3


def _estimator_weight_ft(f_hz: np.ndarray, half_window_s: float) -> np.ndarray:
    """Fourier transform of the estimator's weight on the instantaneous beat, 3 (a^2 - s^2) / (4 a^3)."""
    x = 2 * np.pi * np.asarray(f_hz, dtype=np.float64) * half_window_s
    small = np.abs(x) < 1e-3
    xs = np.where(small, 1.0, x)
    return np.where(small, 1.0 - x * x / 10, 3 * (np.sin(xs) - xs * np.cos(xs)) / xs ** 3)


def linearization_covariance(d_m, plain, residual_hz: float, bandwidth_hz: float, *, ramp_s: float,
                             rate_hz_per_s: float, use_fraction: float = RANGE_WINDOW_FRACTION,
                             n_freq: int = 40001) -> np.ndarray:
    """``C_lin`` (m^2) of the module docstring: the plates' range errors from a residual chirp error of
    RMS ``residual_hz``, flat to ``bandwidth_hz``; ``plain[i]`` False for a compensated plate (no term)."""
    d = np.asarray(d_m, dtype=np.float64)
    f = np.linspace(0.0, bandwidth_hz, n_freq)
    g2 = _estimator_weight_ft(f, 0.5 * use_fraction * ramp_s) ** 2
    tau = 2 * d / C_M_PER_S
    h = (1 - np.exp(-2j * np.pi * f[None, :] * tau[:, None])) * np.asarray(plain, dtype=bool)[:, None]
    integrand = g2[None, None, :] * np.real(h[:, None, :] * np.conj(h[None, :, :]))
    scale = (C_M_PER_S / (2 * rate_hz_per_s)) ** 2 * residual_hz ** 2 / bandwidth_hz
    return scale * np.trapezoid(integrand, f, axis=-1)


def line_chi2(d, e, cov) -> tuple[float, np.ndarray]:
    """Generalised least squares of ``e = offset + scale d`` under covariance ``cov``: (chi-square, residual)."""
    d, e = np.asarray(d, dtype=np.float64), np.asarray(e, dtype=np.float64)
    a = np.stack([np.ones_like(d), d], axis=1)
    ci = np.linalg.inv(cov)
    theta = np.linalg.solve(a.T @ ci @ a, a.T @ ci @ e)
    r = e - a @ theta
    return float(r @ ci @ r), r


def chi2_limit(dof: int) -> float:
    return float(2 * gammaincinv(dof / 2, 0.999))


def residual_of(lin) -> tuple[float, float]:
    """(RMS residual chirp error, learning bandwidth) the linearization reports for the drive it kept."""
    kept = lin.iterations[int(lin.meta["best_iteration"])]
    return 0.5 * (kept["up_error_hz"] + kept["down_error_hz"]), float(lin.meta["learning_bandwidth_hz"])


# -- the model alone (fast) ----------------------------------------------------------------------------
RAMP_S, RATE = 80e-6, 8.6e9 / 80e-6                       # config/sim_far.toml's chirp
D5 = np.array([0.8, 5.0, 20.0, 45.0, 45.0])               # the four plates, then 45 m through the plain front end
PLAIN5 = np.array([True, True, True, False, True])
S5 = np.array([1.0, 2.2, 10.0, 22.0, 23.0]) * 1e-6        # their standard errors on this bench
# this bench's plate errors without noise: the sim's laser model under a learned drive, through the
# estimator's weight (plain front end), 0 compensated; plus a 1.5 um offset
BENCH5 = np.array([1.1, 7.7, 36.7, 0.0, 95.7]) * 1e-6 + 1.5e-6


def test_linearization_term_is_a_slope_error_of_the_predicted_size():
    """For round trips short against 1/B the term is a common range scale error d sigma_eps with
    sigma_eps = (sigma / kappa) sqrt(3 / (4 B a^3)) (module docstring), the same on every plain plate."""
    d = np.array(PLATES_M)
    cov = linearization_covariance(d, [True] * 4, 41e3, 1e6, ramp_s=RAMP_S, rate_hz_per_s=RATE)
    sigma_eps = 41e3 / RATE * np.sqrt(3 / (4 * 1e6 * (0.45 * RAMP_S) ** 3))
    assert sigma_eps == pytest.approx(1.5e-6, rel=0.05)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), d * sigma_eps, rtol=0.03)
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert corr.min() > 0.99                                       # one scale: fully correlated
    # a compensated measurement carries none of it
    comp = linearization_covariance(d, [True, True, True, False], 41e3, 1e6, ramp_s=RAMP_S, rate_hz_per_s=RATE)
    assert comp[3, 3] == 0.0 and comp[:3, :3] == pytest.approx(cov[:3, :3])


def test_chi2_passes_this_bench_and_fails_a_far_nonlinearity():
    """This bench's deterministic pattern passes with room; a range error quadratic in d, +-0.2 mm at
    45 m on top of it, fails; so does the pattern without the linearization's term, which is what made
    the old chi-square pass or fail with the noise draw."""
    cov = np.diag(S5 ** 2) + linearization_covariance(D5, PLAIN5, 39e3, 1e6, ramp_s=RAMP_S, rate_hz_per_s=RATE)
    lim = chi2_limit(D5.size - 2)
    assert line_chi2(D5, BENCH5, cov)[0] < 0.25 * lim
    assert line_chi2(D5, BENCH5, np.diag(S5 ** 2))[0] > 0.6 * lim  # no term: a fair share of draws fail
    for amp in (0.2e-3, -0.2e-3):
        assert line_chi2(D5, BENCH5 + amp * (D5 / 45.0) ** 2, cov)[0] > lim, amp
    # with noise: the 99.9 % level holds (the slope error drawn from the model, not the bench's value)
    rng = np.random.default_rng(7)
    chi = [line_chi2(D5, 1.5e-6 + rng.normal(0.0, 1.5e-6) * D5 * PLAIN5 + rng.normal(0.0, S5), cov)[0]
           for _ in range(400)]
    assert np.mean(np.array(chi) > lim) < 0.01


# -- the bench (slow) ------------------------------------------------------------------------------------
def _plate(inst, d: float, lin, front_end: str | None = None):
    """The plate at ``d`` as the range calibration measures it, or through ``front_end`` ("on": phase
    compensated, "off": plain) instead of the request's automatic choice."""
    inst.set_scene(plate_scene(d, size_m=max(0.6, 0.02 * d)))
    if front_end is None:
        return measure_plate(inst, inst.optics, d, lin, inst.applied)
    req = dataclasses.replace(plate_request(inst.optics, max(2.0, 1.5 * d)), phase_noise_compensation=front_end)
    res = inst.run_scan(req, lambda _p: None, threading.Event(), lin)
    assert not res.partial
    m = plate_measurement(res.points, d, delay_s=float(lin.meta["mzi_delay_s"]),
                          zero_offset_used_m=inst.applied.zero_offset_m)
    return dataclasses.replace(m, phase_noise_compensation=front_end)


@pytest.mark.slow  # one linearization and five plate scans (~25-45 s)
@pytest.mark.parametrize("laser", ["dfb_broad_linewidth", "dfb_default"])
def test_plates_0p8_to_45m_on_one_line(laser):
    cfg = load_config("config/sim_far.toml", environ={
        "LIDARD__SIM__TOLERANCES__ENABLED": "false", "LIDARD__SIM__EFFECTS__PHASE_NOISE": "false",
        "LIDARD__LASER": laser})
    assert cfg.chirp.linear_window == "range"      # the far-range config linearizes the whole range window
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    try:
        lin = inst.linearize()
        ms = [_plate(inst, d, lin) for d in PLATES_M] + [_plate(inst, PLATES_M[-1], lin, "off")]
    finally:
        inst.close()
    d = np.array([m.known_range_m for m in ms])
    e = np.array([m.raw_range_m - m.known_range_m for m in ms])
    s = np.maximum([m.sem_m for m in ms], 1e-6)     # the standard errors, floored at 1 um
    plain = np.array([m.phase_noise_compensation != "on" for m in ms])
    assert plain.tolist() == [True, True, True, False, True]     # the front ends the docstring describes
    # the specification: the plates as the calibration measures them, on their best line
    k = len(PLATES_M)
    a = np.stack([np.ones(k), d[:k]], axis=1)
    coef = np.linalg.lstsq(a / s[:k, None], e[:k] / s[:k], rcond=None)[0]
    r = e[:k] - a @ coef
    assert np.max(np.abs(r)) <= MAX_DEPARTURE_M, f"departure from the best line {r * 1e3} mm (errors {e * 1e3} mm)"
    # consistency: every measurement, with the linearization's residual chirp error
    sigma_hz, bandwidth_hz = residual_of(lin)
    assert 0 < sigma_hz < 200e3 and bandwidth_hz > 0     # a converged linearization of this bench
    cov = np.diag(s ** 2) + linearization_covariance(d, plain, sigma_hz, bandwidth_hz, ramp_s=cfg.chirp.ramp_s,
                                                     rate_hz_per_s=cfg.chirp.rate_hz_per_s)
    chi2, _ = line_chi2(d, e, cov)
    dof = d.size - 2
    assert chi2 <= chi2_limit(dof), (f"chi-square {chi2:.1f} for {dof} dof (errors {e * 1e3} mm, standard errors "
                                     f"{s * 1e3} mm, residual chirp error {sigma_hz / 1e3:.1f} kHz)")
