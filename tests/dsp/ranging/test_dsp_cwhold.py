"""The held segment's drift (lidard.dsp.ranging.cwhold): measured from a monitor-MZI fringe, taken out of the CW
beat, and the three-segment frame where the real receiver's two regimes meet (|f_D| = f_R).

Signals are built from the physics: the MZI fringe cos(2 pi int_{t - tau_m}^t nu + phase noise), a
return's CW beat cos(2 pi int_{t - tau}^t nu - 2 pi f_D t), ramp beats |f_R -/+ f_D|."""

import dataclasses

import numpy as np
import pytest

from lidard.dsp.ranging.cwhold import HoldProfile, dechirp_peak, hold_profile
from lidard.dsp.frame import FrameDsp
from lidard.dsp.spectrum.rangefft import C_M_PER_S
from lidard.dsp.spectrum.window import get_window

WL = 1.55e-6
KAPPA = 8.6e9 / 80e-6
TAU_M = 200e-9
FS_MZI = 200e6
T_HOLD = 78e-6


def _drift_hz(t_s):
    """A DFB's thermal relaxation after the drive stops: two first-order terms, 650 MHz in all."""
    return -(450e6 * (1 - np.exp(-t_s / 8e-6)) + 200e6 * (1 - np.exp(-t_s / 30e-6)))


def _integral_hz_s(t_s, delay_s):
    """int_{t - delay}^{t} nu(s) ds of the drift, in closed form."""
    def prim(t):
        return -(450e6 * (t + 8e-6 * np.exp(-t / 8e-6)) + 200e6 * (t + 30e-6 * np.exp(-t / 30e-6)))
    return prim(t_s) - prim(t_s - delay_s)


def _fringes(n_avg, rng, linewidth_hz=500e3, quadrature=False):
    t = np.arange(int(T_HOLD * FS_MZI)) / FS_MZI
    psi = 2 * np.pi * _integral_hz_s(t, TAU_M) + 0.7
    # the laser's phase noise over the monitor delay: phi(t) - phi(t - tau_m), variance 2 pi lw tau_m
    steps = rng.standard_normal((n_avg, t.size + int(TAU_M * FS_MZI))) * np.sqrt(2 * np.pi * linewidth_hz / FS_MZI)
    phi = np.cumsum(steps, axis=1)
    dphi = phi[:, int(TAU_M * FS_MZI):] - phi[:, :t.size]
    x = np.exp(1j * (psi + dphi)) if quadrature else np.cos(psi + dphi)
    return t, x + 0.05 * rng.standard_normal(x.shape)


def _ramps(n_avg, start, quadrature, up_sign):
    """1 us up ramp and 1 us down ramp of the MZI fringe (beat kappa tau_m = 21.5 MHz): the up ramp
    raises nu when ``up_sign`` is +1 (a quadrature monitor's I + jQ then turns counter-clockwise)."""
    t = np.arange(start // 2) / FS_MZI
    ph = 2 * np.pi * KAPPA * TAU_M * t * up_sign
    ramps = np.concatenate([ph, ph[-1] - 2 * np.pi * KAPPA * TAU_M * t * up_sign])
    z = np.exp(1j * ramps) if quadrature else np.cos(ramps)
    return np.broadcast_to(z, (n_avg, start))


@pytest.mark.parametrize("quadrature, up_sign", [(False, 1), (True, 1), (True, -1)])
def test_hold_profile_recovers_the_drift_through_phase_noise(quadrature, up_sign):
    # the drift continues the down ramp's direction (nu falls in the chirp's frame); a quadrature
    # monitor whose I + jQ turns the other way (up_sign -1) must give the same profile
    rng = np.random.default_rng(3)
    t, x = _fringes(256, rng, quadrature=quadrature)
    if quadrature and up_sign < 0:
        x = np.conj(x)
    start = 400                                   # the record's hold begins here (2 us of ramps before)
    rec = np.concatenate([_ramps(x.shape[0], start, quadrature, up_sign), x], axis=1)
    prof = hold_profile(rec, FS_MZI, start, TAU_M)
    tp = prof.t0_s + prof.dt_s * np.arange(len(prof.nu_hz)) - start / FS_MZI
    truth = _drift_hz(tp) - _drift_hz(tp[0])
    excursion = np.ptp(truth)
    assert excursion > 500e6
    err = np.asarray(prof.nu_hz) - truth            # signed, in the chirp's frame; past the Hilbert edge
    assert np.max(np.abs(err[len(err) // 10:])) < 0.005 * excursion
    # placed on the record's time axis, half the monitor delay early (the fringe is nu(t - tau_m / 2))
    assert prof.t0_s == pytest.approx(start / FS_MZI - TAU_M / 2)


def test_hold_profile_refuses_a_hold_outside_the_record():
    with pytest.raises(ValueError, match="hold from sample"):
        hold_profile(np.zeros((4, 100)), FS_MZI, 95, TAU_M)
    with pytest.raises(ValueError, match="nu_hz"):
        HoldProfile(0.0, 1e-7, (1.0,))
    with pytest.raises(ValueError, match="t0_s"):
        HoldProfile.from_dict({"dt_s": 1e-7, "nu_hz": [0.0, 1.0]})


FS = 20e6


def _profile(t0_s=0.0):
    tp = np.arange(0, T_HOLD + 1e-6, 1e-7)
    return HoldProfile(t0_s, 1e-7, tuple(_drift_hz(tp) - _drift_hz(0.0)))


def _cw_beat(range_m, f_d_hz, t_s, n_avg, rng, snr_amp=0.3):
    """A return's CW beat: 2 pi int_{t - tau}^t nu - 2 pi f_D t (real receiver), noisy records."""
    tau = 2 * range_m / C_M_PER_S
    phase = 2 * np.pi * (_integral_hz_s(t_s, tau) - tau * _drift_hz(0.0)) - 2 * np.pi * f_d_hz * t_s
    return np.cos(phase + rng.uniform(0, 2 * np.pi, (n_avg, 1))) + snr_amp * rng.standard_normal((n_avg, t_s.size))


@pytest.mark.parametrize("range_m, v_mps", [(1.9, -1.05), (1.0, 0.56), (0.6, -0.2)])
def test_dechirped_cw_beat_is_one_sharp_tone_at_the_doppler_shift(range_m, v_mps):
    rng = np.random.default_rng(7)
    t = np.arange(int(0.25 * T_HOLD * FS), int(T_HOLD * FS)) / FS      # the DSP skips the first quarter
    f_d = -2 * v_mps / WL
    cw = _cw_beat(range_m, f_d, t, 4, rng)[None]
    tau = np.array([2 * range_m / C_M_PER_S])
    band = (np.array([0.5 * abs(f_d)]), np.array([1.5 * abs(f_d)]))
    side = np.array([np.sign(v_mps)])                                   # the tone at -f_D = 2 v / lambda
    w = get_window("hann", t.size)
    f, p, noise, shoulder = dechirp_peak(cw, t, _profile(), tau, FS, band, side, w)
    bin_hz = FS / t.size
    assert abs(f[0] - abs(f_d)) < 0.03 * bin_hz                          # ~0.5 kHz: 0.4 mm/s
    assert p[0] > 100 * noise[0]
    assert p[0] > 100 * shoulder[0]              # one tone: its shoulders hold sidelobes and noise only
    # without the drift taken out, the beat's peak sits tau nu' off |f_D| (several mm of range): the
    # error the regime search's bands allow for (lidard.dsp.ranging.threeseg.RHO_MAX)
    flat = HoldProfile(0.0, 1e-7, tuple(np.zeros(len(_profile().nu_hz))))
    f0 = dechirp_peak(cw, t, flat, tau, FS, band, side, w).f_hz
    assert abs(f0[0] - abs(f_d)) > 0.3 * bin_hz
    assert abs(f0[0] - abs(f_d)) > 20 * abs(f[0] - abs(f_d))
    # the other side holds the mirror half, shifted by 2 tau nu' (and spread): never the estimate
    fm, pm, _, _ = dechirp_peak(cw, t, _profile(), tau, FS, band, -side, w)
    assert abs(fm[0] - abs(f_d)) > 20 * abs(f[0] - abs(f_d))


def _records(dsp, range_m, v_mps, rng, n_avg=4, noise=0.3):
    """Records of the three-segment chirp: up |f_R - f_D|, down |f_R + f_D|, the CW beat with the drift."""
    f_r = 2 * KAPPA * range_m / C_M_PER_S
    f_d = -2 * v_mps / WL
    r = dsp.ramp_samples
    t_r = np.arange(r) / FS
    t_c = (2 * r + np.arange(dsp.cw_samples)) / FS
    up = np.cos(2 * np.pi * (f_r - f_d) * t_r + 0.3)
    dn = np.cos(2 * np.pi * (f_r + f_d) * t_r + 1.1)
    x = np.concatenate([np.broadcast_to(up, (n_avg, r)), np.broadcast_to(dn, (n_avg, r)),
                        _cw_beat(range_m, f_d, t_c - 2 * r / FS, n_avg, rng, snr_amp=0.0)], axis=1)
    return (x + noise * rng.standard_normal(x.shape))[None]


def _frame_dsp():
    return FrameDsp(ramp_samples=int(FS * 80e-6), fs_hz=FS, chirp_rate_hz_per_s=KAPPA, wavelength_m=WL,
                    max_range_m=2.0, max_speed_mps=10.0, cw_samples=int(FS * T_HOLD), max_returns=2)


def _with_drift(dsp):
    """``dsp`` with the synthetic drift as its hold profile (the hold starts after the two ramps)."""
    return dataclasses.replace(dsp, hold_profile=_profile(t0_s=2 * dsp.ramp_samples / FS).as_dict())


def _assert_one_point(res, range_m, v):
    """One valid point in the pixel, at the range to 1 mm and the velocity to 0.01 m/s."""
    assert res.valid[0].sum() == 1
    k = int(np.argmax(res.valid[0]))
    assert res.range_m[0, k] == pytest.approx(range_m, abs=1e-3)
    assert res.velocity_mps[0, k] == pytest.approx(v, abs=0.01)


@pytest.mark.parametrize("range_m, factor", [(1.2, 1.0), (1.2, -1.0), (0.5, 0.98), (1.8, -1.02), (0.9, 1.04)])
def test_frame_where_the_regimes_meet_is_ranged_with_the_hold_profile(range_m, factor):
    # |f_D| = factor x f_R: one ramp beat at (or near) DC; the sign of v is the sign of factor's f_D
    f_r = 2 * KAPPA * range_m / C_M_PER_S
    v = -factor * f_r * WL / 2
    rng = np.random.default_rng(11)
    dsp = _frame_dsp()
    x = _records(dsp, range_m, v, rng)
    without = dsp.process(x)
    assert not without.valid.any()                             # ambiguous: drawn or absent, never valid
    res = _with_drift(dsp).process(x)
    _assert_one_point(res, range_m, v)


def test_hold_profile_does_not_add_points_to_a_static_target():
    # a static target's CW beat sits at DC: no boundary candidate, the same single point as without
    rng = np.random.default_rng(5)
    dsp = _frame_dsp()
    x = _records(dsp, 0.3, 0.0, rng)
    a, b = dsp.process(x), _with_drift(dsp).process(x)
    assert a.valid.sum() == b.valid.sum() == 1
    assert np.array_equal(a.range_m[a.valid], b.range_m[b.valid])


def test_candidates_in_several_passes_give_the_same_points(monkeypatch):
    # three pixels where the regimes meet, one batch; memory-bounded passes of one candidate each
    import lidard.dsp.ranging.cwhold as cwhold
    rng = np.random.default_rng(2)
    dsp = _frame_dsp()
    dsp = _with_drift(dsp)
    cases = [(0.5, 1.0), (1.2, -0.99), (1.7, 1.02)]
    x = np.concatenate([_records(dsp, r, -f * 2 * KAPPA * r / C_M_PER_S * WL / 2, rng) for r, f in cases])
    whole = dsp.process(x)
    monkeypatch.setattr(cwhold, "PASS_ELEMENTS", 1)
    split = dataclasses.replace(dsp).process(x)
    assert whole.valid.sum(axis=1).tolist() == [1, 1, 1]
    np.testing.assert_array_equal(whole.range_m[whole.valid], split.range_m[split.valid])
    assert whole.range_m[whole.valid] == pytest.approx([r for r, _ in cases], abs=1e-3)


def test_a_noise_peak_is_not_paired_on_the_true_returns_spread_cw_beat():
    # 1 m approaching at 0.99 x the boundary speed: the up beat sits at DC (not detected), and a spurious
    # peak in the up ramp (2.5 x the down beat, as a noise false alarm once gave) pairs with it into
    # a "not folded" reading whose |f_D| lies inside the RHO_MAX spread allowed around the true return's
    # CW beat. With the measured drift the band is where that reading's beat must be: refused, and the
    # lone down peak is ranged at 1 m.
    rng = np.random.default_rng(4)
    dsp = _frame_dsp()
    range_m = 1.0
    f_r = 2 * KAPPA * range_m / C_M_PER_S
    v = -0.99 * f_r * WL / 2
    x = _records(dsp, range_m, v, rng)
    f_dn = abs(f_r - 2 * v / WL)                     # |f_R + f_D|, f_D = -2 v / lambda
    r = dsp.ramp_samples
    x[..., :r] += 0.5 * np.cos(2 * np.pi * 2.5 * f_dn * np.arange(r) / FS + 0.4)
    res = _with_drift(dsp).process(x)
    _assert_one_point(res, range_m, v)


def test_a_spurious_peak_at_twice_a_returns_doppler_is_not_a_boundary_target():
    # a target at 0.63 m receding at 0.19 m/s, off the boundary, and a spurious up-ramp peak at 2 |f_D|:
    # read as a lone peak whose partner sits at DC it predicts a CW tone at |f_D|, which the true
    # return's CW beat supplies. That tone is the true point's: one point, at 0.63 m (a hold-out pixel)
    rng = np.random.default_rng(6)
    dsp = _frame_dsp()
    range_m, v = 0.63, 0.19
    x = _records(dsp, range_m, v, rng)
    r = dsp.ramp_samples
    x[..., :r] += 0.5 * np.cos(2 * np.pi * (2 * 2 * v / WL - 3e3) * np.arange(r) / FS + 0.9)
    res = _with_drift(dsp).process(x)
    _assert_one_point(res, range_m, v)


def test_a_far_returns_cw_line_dechirped_at_a_near_round_trip_is_not_a_tone():
    # a wall beyond the range gate still beats in the held segment within the Doppler band, smeared by
    # the hold's drift over its round trip; dechirped with the round trip of a noise peak on one ramp
    # (a near range) it stays smeared: its peak does not stand TONE_CONTRAST over its shoulders, while
    # a return inside the gate dechirped with its own round trip is one tone that does. The window the
    # DSP dechirps: the hold after its first 2 % (lidard.dsp.ranging.threeseg.DECHIRP_SKIP_FRACTION).
    from lidard.dsp.ranging.cwhold import TONE_CONTRAST
    from lidard.dsp.ranging.threeseg import DECHIRP_SKIP_FRACTION
    rng = np.random.default_rng(3)
    t = np.arange(int(DECHIRP_SKIP_FRACTION * T_HOLD * FS), int(T_HOLD * FS)) / FS
    far_m, f_d = 5.5, -30e3                                       # a wall's slow drift of 2 cm/s
    cw = _cw_beat(far_m, f_d, t, 10, rng, snr_amp=0.05)[None]
    w = get_window("hann", t.size)
    band = (np.array([0.0]), np.array([1e6]))
    side = np.array([1.0])
    near = dechirp_peak(cw, t, _profile(), np.array([2 * 0.2 / C_M_PER_S]), FS, band, side, w)
    assert near.power[0] > 20 * near.noise[0]                    # a strong line: the median test alone passes it
    assert near.power[0] < TONE_CONTRAST * near.shoulder[0]
    for range_m in (0.3, 1.0, 1.9):                               # where the regimes can meet, inside the gate
        cw_in = _cw_beat(range_m, f_d, t, 10, rng, snr_amp=0.05)[None]
        own = dechirp_peak(cw_in, t, _profile(), np.array([2 * range_m / C_M_PER_S]), FS, band, side, w)
        assert abs(own.f_hz[0] - abs(f_d)) < FS / t.size          # the tone at |f_D|
        # its shoulders hold the tail of its own mirror half (spread by 2 tau nu', nearer the tone the
        # later the hold): the farther the return, the less the margin (~24x at 1.9 m here)
        assert own.power[0] > 1.5 * TONE_CONTRAST * own.shoulder[0], (range_m, own.power[0] / own.shoulder[0])


@pytest.mark.parametrize("noise_amp", [4.2, 2.5])
def test_a_tone_in_noise_at_one_record_is_judged_by_its_snr_alone(noise_amp):
    # the default scan averages one record: a shoulder of noise then fluctuates widely, and asking every
    # tone to stand TONE_CONTRAST over it dropped ~20 % of boundary points that passed PEAK_SNR; the
    # contrast applies only to a shoulder that is a line (SHOULDER_LINE over the median)
    from lidard.dsp.ranging.cwhold import PEAK_SNR, TONE_CONTRAST, is_tone
    from lidard.dsp.ranging.threeseg import DECHIRP_SKIP_FRACTION
    rng = np.random.default_rng(11)
    t = np.arange(int(DECHIRP_SKIP_FRACTION * T_HOLD * FS), int(T_HOLD * FS)) / FS
    m, range_m = 300, 0.6
    cw = np.stack([_cw_beat(range_m, -200e3, t, 1, rng, snr_amp=noise_amp) for _ in range(m)])
    pk = dechirp_peak(cw, t, _profile(), np.full(m, 2 * range_m / C_M_PER_S), FS,
                      (np.full(m, 100e3), np.full(m, 300e3)), np.ones(m), get_window("hann", t.size))
    by_snr = pk.power >= PEAK_SNR * pk.noise
    assert 0.3 < by_snr.mean() <= 1.0                          # near the detection threshold, or just above
    kept = by_snr & is_tone(pk.power, pk.shoulder, pk.noise)
    assert kept.sum() >= 0.97 * by_snr.sum()
    if by_snr.mean() < 0.9:                                    # control: the unconditional contrast loses more
        assert (by_snr & (pk.power >= TONE_CONTRAST * pk.shoulder)).sum() < 0.9 * by_snr.sum()
