"""MEMS switch dynamics against the dissertation's numbers (§4.2.6, §4.3.6) and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from sim_devices.world.mems import (
    COLUMN_SWITCH,
    ROW_SWITCH,
    SwitchBank,
    SwitchDynamics,
    hysteresis_states,
    mean_path_transmission,
)

US = 1e-6


def step_bank(dyn, t_on=0.0, t_off=None, v=40.0, n=1):
    sw, t, volts = [0], [t_on], [v]
    if t_off is not None:
        sw.append(0)
        t.append(t_off)
        volts.append(0.0)
    return SwitchBank(n, dyn, np.array(sw), np.array(t), np.array(volts))


def test_response_times_are_command_to_90_percent():
    row = step_bank(ROW_SWITCH)
    assert row.transmission(0, 1.0 * US) == pytest.approx(0.9, abs=1e-12)
    col = step_bank(COLUMN_SWITCH)
    assert col.transmission(0, 2.7 * US) == pytest.approx(0.9, abs=1e-12)
    col_off = step_bank(COLUMN_SWITCH, t_on=-1.0, t_off=0.0)  # long on, then off at t=0
    assert col_off.transmission(0, 2.0 * US) == pytest.approx(0.1, abs=1e-12)
    assert col_off.transmission(0, -0.5) == pytest.approx(1.0)
    assert ROW_SWITCH.tau_on_s == pytest.approx(1e-6 / math.log(10))


def test_hysteresis_pull_in_32_release_29():
    up = np.arange(0.0, 40.01, 0.5)
    sweep = np.concatenate([up, up[::-1]])
    state = hysteresis_states(sweep, False, 32.0, 29.0)
    rising = state[: up.size]
    falling = state[up.size:]
    assert up[np.argmax(rising)] == 32.0  # first ON sample on the way up
    v_down = up[::-1]
    assert v_down[np.argmin(falling)] == 29.0  # first OFF sample on the way down
    # between release and pull-in the state is remembered
    assert not hysteresis_states(np.array([30.0, 31.0]), False, 32, 29).any()
    assert hysteresis_states(np.array([30.0, 31.0]), True, 32, 29).all()
    # vectorised over switches (leading axis)
    many = hysteresis_states(np.array([[40.0, 30.0], [30.0, 30.0]]), [False, False], 32, 29)
    np.testing.assert_array_equal(many, [[True, True], [False, False]])


def test_bank_drive_between_release_and_pull_in_does_not_switch():
    bank = SwitchBank(2, ROW_SWITCH, np.array([0, 1, 1]), np.array([0.0, 0.0, 5 * US]),
                      np.array([30.0, 40.0, 30.0]))
    assert bank.transmission(0, 20 * US) == 0.0  # 30 V never pulls in from OFF
    assert bank.transmission(1, 20 * US) == pytest.approx(1.0)  # 30 V holds an ON switch
    assert bank.is_on(np.array([0, 1]), 20 * US).tolist() == [False, True]


def test_command_during_transition_relaxes_from_current_level():
    bank = step_bank(COLUMN_SWITCH, t_on=0.0, t_off=0.5 * US)
    tau_on, tau_off = COLUMN_SWITCH.tau_on_s, COLUMN_SWITCH.tau_off_s
    level = 1 - math.exp(-0.5 * US / tau_on)
    want = level * math.exp(-1.0 * US / tau_off)
    assert bank.transmission(0, 1.5 * US) == pytest.approx(want, rel=1e-12)


def test_mean_window_matches_quadrature_of_closed_form():
    rows = step_bank(ROW_SWITCH)
    cols = step_bank(COLUMN_SWITCH)

    def path(t):  # both switched on at t = 0 from fully off
        return ((1 - math.exp(-t / ROW_SWITCH.tau_on_s))
                * (1 - math.exp(-t / COLUMN_SWITCH.tau_on_s)))

    for start, width in [(0.0, 1 * US), (0.5 * US, 3 * US), (2 * US, 0.2 * US), (0, 40 * US)]:
        want = quad(path, start, start + width, epsabs=1e-16, limit=200)[0] / width
        got = mean_path_transmission(rows, 0, cols, 0, start, start + width)
        assert got[0] == pytest.approx(want, rel=1e-9)
    # zero-width window: instantaneous value
    assert mean_path_transmission(rows, 0, cols, 0, 1 * US, 1 * US)[0] == pytest.approx(path(1 * US))


def test_mean_window_across_events_matches_dense_sampling():
    rng = np.random.default_rng(7)
    n = 3
    t = np.sort(rng.uniform(0, 10 * US, 12))
    sw = rng.integers(0, n, t.size)
    v = rng.choice([0.0, 40.0], t.size)
    rows = SwitchBank(n, ROW_SWITCH, sw, t, v)
    cols = SwitchBank(n, COLUMN_SWITCH, sw[::-1], t, v[::-1])
    r, c = rng.integers(0, n, 20), rng.integers(0, n, 20)
    t0 = rng.uniform(0, 8 * US, 20)
    t1 = t0 + rng.uniform(0.1 * US, 4 * US, 20)
    got = mean_path_transmission(rows, r, cols, c, t0, t1)
    for i in range(20):
        ts = np.linspace(t0[i], t1[i], 200_001)
        y = rows.transmission(r[i], ts) * cols.transmission(c[i], ts)
        assert got[i] == pytest.approx(np.trapezoid(y, ts) / (t1[i] - t0[i]), abs=1e-6)


def test_possibly_lit_over_approximates():
    bank = step_bank(COLUMN_SWITCH, t_on=5 * US, t_off=10 * US)
    t0 = np.array([0.0, 4 * US, 30 * US, 11 * US, 200 * US])
    t1 = t0 + 2 * US
    lit = bank.possibly_lit(0, t0, t1, 1e-6)
    assert lit.tolist() == [False, True, False, True, False]


def test_bad_parameters_rejected():
    with pytest.raises(ValueError):
        SwitchDynamics(1e-6, 1e-6, pull_in_v=29.0, release_v=32.0)
    with pytest.raises(ValueError):
        SwitchDynamics(0.0, 1e-6)
    with pytest.raises(ValueError):
        SwitchBank(1, ROW_SWITCH, np.array([1]), np.array([0.0]), np.array([40.0]))
    with pytest.raises(ValueError):
        mean_path_transmission(step_bank(ROW_SWITCH), 0, step_bank(ROW_SWITCH), 0, 1.0, 0.5)
