"""Phase noise in the synthesized beats (§2.3, eqs. 2-14/2-15), the Brownian bridge for fractional
delays, the shared MZI realization, float64 phase accumulation, and skipping switched-off effects."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_laser
from lidard.physics.budget import LinkParams, asd_components
from lidard.physics.constants import C_M_PER_S
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, MonitorMzi, SynthOutputs, synthesize, trajectory

RAMP_S = 80e-6


def _ideal(excursion_hz, fs_awg=100e6, dtype=np.float64):
    laser = DfbLaser(load_laser("ideal"))
    return trajectory(laser, triangle_drive(excursion_hz, RAMP_S, fs_awg, laser.static_tuning_hz_per_v),
                      fs_awg, dtype=dtype)


class _NoDraws:
    """A stand-in generator that fails the test on any use."""

    def __getattr__(self, name):
        raise AssertionError(f"random generator used ({name}) although the effect is switched off")


def _beat_phase_noise(traj, fs, n, n_seg, tau_s, linewidth_hz, seed, mzi=None):
    """Phase of the I/Q beat relative to the noiseless beat, and the synthesis result."""
    adc = AdcSpec(fs, n, bits=16, input_range_v=4.0, iq=True, quantize=False)
    hits = HitBatch(seg=np.arange(n_seg), tau_s=np.full(n_seg, tau_s), amplitude_v=np.ones(n_seg))
    t0 = np.zeros(n_seg)
    r = synthesize(traj, adc, t0, hits, effects=Effects(linewidth_hz=linewidth_hz), rng=np.random.default_rng(seed),
                   outputs=SynthOutputs(phase_noise=True), mzi=mzi)
    r0 = synthesize(traj, adc, t0, hits, mzi=mzi)
    dphi = np.angle((r.beat + 1j * r.beat_q) * np.conj(r0.beat + 1j * r0.beat_q))
    return dphi, r, r0


@pytest.mark.parametrize("delay_samples", [2.5, 2.3, 7.8])
def test_fractional_delay_phase_noise_variance_is_2_pi_linewidth_tau(delay_samples):
    fs = 100e6
    tau = delay_samples / fs
    lw = 0.1 / (2 * np.pi * tau)                       # Var = 0.1 rad^2: no wrapping
    dphi, _, _ = _beat_phase_noise(_ideal(1e9), fs, 2000, 200, tau, lw, seed=11)
    assert np.var(dphi) == pytest.approx(2 * np.pi * lw * tau, rel=0.02)


def test_integer_delays_use_the_exact_shared_realization_for_beat_and_mzi():
    fs = 100e6
    traj = _ideal(8.6e9)
    n, m, m_mzi = 1500, 3, 5
    lw = 1e6
    dphi, r, r0 = _beat_phase_noise(traj, fs, n, 4, m / fs, lw, seed=2,
                                    mzi=MonitorMzi(m_mzi / fs, 0.3))
    pn, pre = r.phase_noise_rad, r.phase_noise_pre
    assert pn.shape == (4, pre + n)
    k = pre + np.arange(n)
    expected = pn[:, k] - pn[:, k - m]
    assert np.max(np.abs(np.angle(np.exp(1j * (dphi - expected))))) < 1e-9
    # the MZI carries phi(t) - phi(t - tau_m) of the SAME realization on top of its chirp phase
    t = np.arange(n) / fs
    tau_m = m_mzi / fs
    det = traj.phase_at(t) - traj.phase_at(t - tau_m) + 2 * np.pi * np.mod(traj.nu0_hz * tau_m, 1.0)
    assert np.allclose(r0.mzi[0], 0.3 * np.cos(det), atol=1e-9)
    mzi_expected = 0.3 * np.cos(det[None, :] + pn[:, k] - pn[:, k - m_mzi])
    assert np.allclose(r.mzi, mzi_expected, atol=1e-9)


@pytest.mark.parametrize("tau_s, tau_c, excursion, fs", [
    (0.48e-6, 0.64e-6, 1e9, 25e6),                       # Table 2-2 laser, 12 samples (exact delay)
    (0.5e-6, 0.64e-6, 1e9, 25e6),                        # 12.5 samples (Brownian bridge)
    # broad linewidth: the ~3 MHz wide pedestal needs f_b well clear of 0 Hz (its mirror image) and fs/2
    (0.2e-6, load_laser("dfb_broad_linewidth").coherence_time_s, 5e9, 100e6),
])
def test_phase_noise_peak_and_pedestal_follow_eqs_2_14_and_2_15(tau_s, tau_c, excursion, fs):
    # small excursions keep the records short; the physics only needs f_b = excursion tau / T
    n = int(RAMP_S * fs)
    n_seg = 300
    j = int(round(excursion * tau_s))                # integer bin: f_b T = excursion tau
    adc = AdcSpec(fs, n, bits=16, input_range_v=4.0, quantize=False)
    hits = HitBatch(seg=np.arange(n_seg), tau_s=np.full(n_seg, tau_s), amplitude_v=np.full(n_seg, 0.5))
    r = synthesize(_ideal(excursion), adc, np.zeros(n_seg), hits, effects=Effects(linewidth_hz=1 / (np.pi * tau_c)),
                   rng=np.random.default_rng(7))
    x = np.fft.fft(r.beat, axis=1) * np.sqrt(2.0 / (n * fs))          # eq. 2-13 scaling
    coherent = np.mean(x, axis=0)
    peak = np.abs(coherent[j])
    band = slice(j - 3, j + 4)
    pedestal = np.sqrt(np.mean(np.abs(x[:, band] - coherent[band]) ** 2))
    ideal_peak = 0.5 * np.sqrt(RAMP_S / 2)

    d = C_M_PER_S * tau_s / 2
    c = asd_components(LinkParams.table_2_2(coherence_time_s=tau_c, ramp_s=RAMP_S), d)
    c0 = asd_components(LinkParams.table_2_2(coherence_time_s=np.inf, ramp_s=RAMP_S), d)

    def db(a):
        return 20 * np.log10(a)

    assert db(peak / ideal_peak) == pytest.approx(db(c["signal"] / c0["signal"]), abs=0.5)
    assert db(pedestal / ideal_peak) == pytest.approx(db(c["pedestal"] / c0["signal"]), abs=0.5)
    # the effect is large here, so the comparison means something
    assert db(c["signal"] / c0["signal"]) < -5


def test_float32_phase_accumulation_corrupts_the_beat_float64_does_not():
    excursion = 8.6e9
    gamma = excursion / RAMP_S
    fs = 250e6
    n = int(RAMP_S * fs)
    tau = 1.0123e-6                                 # ~150 m, not on the sample grid
    adc = AdcSpec(fs, n, bits=16, input_range_v=4.0, iq=True, quantize=False)
    hits = HitBatch(seg=np.array([0]), tau_s=np.array([tau]), amplitude_v=np.array([1.0]))
    t = np.arange(n) / fs
    ok = t >= tau                                   # before tau the return is from the previous ramp
    nu0 = C_M_PER_S / 1.55e-6
    # ideal centred triangle: nu = -E/2 + gamma t on the up ramp
    analytic = 2 * np.pi * (-excursion * tau / 2 + gamma * (t * tau - tau**2 / 2) + np.mod(nu0 * tau, 1.0))
    err = {}
    for dt in (np.float64, np.float32):
        traj = _ideal(excursion, fs_awg=200e6, dtype=dt)
        r = synthesize(traj, adc, np.array([7 * traj.period_s]), hits)
        z = (r.beat + 1j * r.beat_q)[0]
        err[dt] = np.angle(z[ok] * np.exp(-1j * analytic[ok]))
    assert np.max(np.abs(err[np.float64])) < 1e-5
    # float32: the ~1e6 rad chirp phase has a ~0.06 rad ulp; differencing two such phases leaves
    # errors of ~0.2 rad rms and up to ~1 rad on single samples (useless for the MZI-based ILC and
    # phase-noise compensation, which differentiate or subtract exactly these phases)
    assert np.sqrt(np.mean(err[np.float32] ** 2)) > 0.1
    assert np.max(np.abs(err[np.float32])) > 0.5


def test_switched_off_effects_draw_nothing():
    traj = _ideal(8.6e9)
    adc = AdcSpec(50e6, 400, bits=8)
    hits = HitBatch.from_targets([0, 1], [3.0, 40.0], 0.2)
    # linewidth 0, no noise: not a single draw, also with the MZI on
    r = synthesize(traj, adc, np.zeros(3), hits, effects=Effects(linewidth_hz=0.0, noise_asd_v_per_rthz=0.0),
                   rng=_NoDraws(), mzi=MonitorMzi(20e-9, 0.3))
    assert r.phase_noise_rad is None and np.any(r.beat != 0)
    # a linewidth but nothing to apply it to (no hits, no MZI): no draw either
    r = synthesize(traj, adc, np.zeros(3), None, effects=Effects(linewidth_hz=1e6), rng=_NoDraws())
    assert np.all(r.beat == 0)
    # with a real generator, the phase-noise-free run leaves the state untouched
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    synthesize(traj, adc, np.zeros(3), hits, effects=Effects(linewidth_hz=0.0), rng=rng)
    assert rng.bit_generator.state == state
