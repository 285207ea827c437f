"""Up/down-ramp pairing (eqs. 2-4..2-7) with the sign derived from synthesized optical phases."""

import numpy as np
import pytest

from lidard.dsp.ranging.estimators import estimate
from lidard.dsp.spectrum.rangefft import C_M_PER_S, RangeFFT
from lidard.dsp.ranging.velocity import pair_up_down
from lidard.dsp.spectrum.window import DspInputError

GAMMA = 1.25e14  # Table 2-2: 10 GHz in 80 us
LAM = 1550e-9
F0 = C_M_PER_S / LAM
FS = 250e6
N = 4096


def beat(d0_m, v_mps, ramp, iq=False):
    """Beat of LO and return for a target at d0 moving at v (receding positive), from the optical
    phases: LO phase 2 pi (f0 t +- gamma t^2 / 2), return = LO phase at t - tau(t), with
    tau(t) = 2 (d0 + v t) / c.  The difference is expanded analytically so no 1e8-cycle phases cancel."""
    t = np.arange(N) / FS
    tau = 2 * (d0_m + v_mps * t) / C_M_PER_S
    sgn = 1.0 if ramp == "up" else -1.0
    phase = 2 * np.pi * (F0 * tau + sgn * GAMMA * (t * tau - tau**2 / 2))
    return np.exp(1j * phase) if iq else np.cos(phase)


def measure(x, iq=False):
    rf = RangeFFT(N, FS, GAMMA, window="hann", iq=iq)
    p = rf.power(x[None])
    p[:, np.abs(rf.bins) < 3] = 0  # ignore DC
    k = rf.index_to_bin(np.argmax(p, axis=-1))
    return estimate(x[None], k, window="hann")[0] * rf.delta_f


def test_receding_target_gives_positive_velocity():
    d, v = 30.0, 5.0  # receding at 5 m/s
    f_up, f_down = measure(beat(d, v, "up")), measure(beat(d, v, "down"))
    # Physics: receding -> Doppler lowers the return, so the up-ramp beat is the HIGHER one.
    assert f_up > f_down
    r, vel, ok = pair_up_down([f_up], [f_down], [True], [True], GAMMA, LAM)
    assert ok[0]
    assert vel[0] == pytest.approx(v, abs=0.02)
    # range at mid-ramp: the target moves v T / 2 during the ramp
    assert r[0] == pytest.approx(d + v * N / FS / 2, abs=2e-3)
    # and the dissertation's approaching speed V is the negative of ours
    assert LAM * (f_down - f_up) / 4 == pytest.approx(-v, abs=0.02)


def test_approaching_target_gives_negative_velocity():
    d, v = 40.0, -8.0  # range beat 33 MHz > Doppler 10.3 MHz: no folding
    f_up, f_down = measure(beat(d, v, "up")), measure(beat(d, v, "down"))
    r, vel, ok = pair_up_down([f_up], [f_down], [True], [True], GAMMA, LAM)
    assert ok[0] and vel[0] == pytest.approx(v, abs=0.02) and r[0] == pytest.approx(d, abs=5e-3)


def test_doppler_folding_with_real_beats_is_marked_invalid():
    d, v = 5.0, -20.0  # range beat 4.2 MHz < Doppler 25.8 MHz: the up-ramp beat folds
    f_r, f_d = 2 * GAMMA * d / C_M_PER_S, 2 * abs(v) / LAM
    assert f_d > f_r
    f_up, f_down = measure(beat(d, v, "up")), measure(beat(d, v, "down"))
    assert f_up == pytest.approx(f_d - f_r, rel=1e-3)  # folded through zero
    # Naive eqs. 2-6/2-7 on |f| give a wrong range (this is what must not be reported):
    naive_r = C_M_PER_S * (f_up + f_down) / (4 * GAMMA)
    assert abs(naive_r - d) > 10
    r, vel, ok = pair_up_down([f_up], [f_down], [True], [True], GAMMA, LAM, max_speed_mps=30.0)
    assert not ok[0] and r[0] == 0.0 and vel[0] == 0.0
    # A far target with the same speed is unambiguous and valid.
    far_up, far_down = measure(beat(60.0, v, "up")), measure(beat(60.0, v, "down"))
    r, vel, ok = pair_up_down([far_up], [far_down], [True], [True], GAMMA, LAM, max_speed_mps=30.0)
    assert ok[0] and r[0] == pytest.approx(60.0, abs=5e-3) and vel[0] == pytest.approx(v, abs=0.02)


def test_iq_resolves_the_folding():
    d, v = 5.0, -20.0
    f_up = measure(beat(d, v, "up", iq=True), iq=True)
    f_down = -measure(beat(d, v, "down", iq=True), iq=True)  # conjugated down-ramp convention
    assert f_up < 0  # the sign is measured
    r, vel, ok = pair_up_down([f_up], [f_down], [True], [True], GAMMA, LAM, iq=True, max_speed_mps=30.0)
    assert ok[0] and r[0] == pytest.approx(d, abs=5e-3) and vel[0] == pytest.approx(v, abs=0.02)


def test_beat_too_close_to_dc_is_invalid():
    f_up, f_down = np.array([[0.05e6, 20e6]]), np.array([[30e6, 20.5e6]])
    ok_in = np.ones((1, 2), dtype=bool)
    _, _, ok = pair_up_down(f_up, f_down, ok_in, ok_in, GAMMA, LAM, min_beat_hz=0.5e6)
    assert ok.tolist() == [[False, True]]


def test_pairing_several_returns_by_range_consistency():
    # Two ramps x three targets; down-ramp detections in a different (strength) order.
    d = np.array([[15.0, 40.0, 25.0], [12.0, 55.0, 30.0]])
    v = np.array([[2.0, -3.0, 0.5], [-1.0, 4.0, 0.0]])
    f_r = 2 * GAMMA * d / C_M_PER_S
    f_dop = 2 * v / LAM
    f_up = f_r + f_dop
    f_down = (f_r - f_dop)[:, [2, 0, 1]]
    ok_in = np.ones((2, 3), dtype=bool)
    r, vel, ok = pair_up_down(f_up, f_down, ok_in, ok_in, GAMMA, LAM, max_speed_mps=5.0)
    assert ok.all()  # every range beat (>= 10 MHz) is above the 6.5 MHz Doppler limit
    np.testing.assert_allclose(r, d, atol=1e-9)
    np.testing.assert_allclose(vel, v, atol=1e-9)


def test_missing_partner_and_speed_limit():
    f_up = np.array([[20e6, 50e6]])
    f_down = np.array([[20.2e6, 0.0]])
    _, _, ok = pair_up_down(f_up, f_down, [[True, True]], [[True, False]], GAMMA, LAM, max_speed_mps=1.0)
    assert ok.tolist() == [[True, False]]
    # 0.2 MHz mismatch = 0.08 m/s: beyond a 0.05 m/s limit -> not paired
    _, _, ok = pair_up_down(f_up, f_down, [[True, True]], [[True, False]], GAMMA, LAM, max_speed_mps=0.05)
    assert not ok.any()


def test_bad_arguments_are_named():
    with pytest.raises(DspInputError, match="shape mismatch"):
        pair_up_down([[1.0], [2.0]], [[1.0]], [[True], [True]], [[True]], GAMMA, LAM)
    with pytest.raises(DspInputError, match="wavelength_m"):
        pair_up_down([1.0], [1.0], [True], [True], GAMMA, -1.0)
    with pytest.raises(DspInputError, match="NaN"):
        pair_up_down([np.nan], [1.0], [True], [True], GAMMA, LAM)
