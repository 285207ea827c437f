"""The controller's HV reaches the switches: pull-in / release hysteresis per switch (§4.2.6,
Fig. 4-15a: on at 32 V, off at 29 V for the 20x20), a seeded switch-to-switch spread, the hold
drive (pull in at the HV, hold lower) and its faster release, and the self-test's HV message."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.controller import protocol as ctl_p
from drivers.fpsa import protocol as p
from lidard.config import CONFIG_DIR, load_config
from lidard.instrument.selftest_analysis import hv_margin_problem, hv_pull_in_problem
from sim_devices.bench.bench import Bench
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.world.mems import SwitchDynamics, switch_thresholds

PULL_IN_V, RELEASE_V = 32.0, 29.0  # §4.2.6
US = 1e-6


def _fpga(drive: HvDrive, rc_s: float = 0.0, spread_v: float = 0.0, seed: int = 0):
    dyn = SwitchDynamics(0.9 * US, 0.9 * US, PULL_IN_V, RELEASE_V, discharge_rc_s=rc_s)
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(rows=20, cols=20, bonded_rows=tuple(range(20)), row_dynamics=dyn,
                                    col_dynamics=dyn, threshold_spread_v=spread_v, seed=seed))
    box = {"drive": drive}
    sim.supply = lambda: box["drive"]
    _send(sim, p.Cmd.RESET)
    clock.advance(100 * US)
    return clock, sim, box


def _send(sim, cmd, payload=b""):
    r = p.decode_response(p.decode_frame(sim.feed(p.encode_frame(1, cmd, payload))))
    assert r.ok, r


def _lit_after(clock, sim, row, col, wait_s=20 * US):
    _send(sim, p.Cmd.SET_PIXEL, p.encode_set_pixel(row, col))
    clock.advance(wait_s)
    t = clock.now()
    rows, cols, trans = sim.lit_beams(t, t)
    return {(int(r), int(c)): float(x) for r, c, x in zip(rows, cols, trans)}


def test_no_pull_in_below_the_pull_in_voltage():
    clock, sim, _ = _fpga(HvDrive(31.9))  # above release, below pull-in
    assert _lit_after(clock, sim, 2, 3) == {}
    clock, sim, _ = _fpga(HvDrive(32.1))
    assert _lit_after(clock, sim, 2, 3) == {(2, 3): pytest.approx(1.0, abs=1e-6)}


def test_hv_between_release_and_pull_in_holds_on_switches_but_pulls_in_no_new_one():
    clock, sim, box = _fpga(HvDrive(35.0, hold_v=30.0))
    lit = _lit_after(clock, sim, 2, 3)
    assert lit == {(2, 3): pytest.approx(1.0, abs=1e-6)}      # held at 30 V long after the boost
    kinds, lines, ts, vs = sim.drive_events()
    assert 30.0 not in vs  # the hold is applied per switch from the hold log, not as a line change
    box["drive"] = HvDrive(30.0)                                 # HV itself between 29 and 32 V
    assert _lit_after(clock, sim, 4, 5) == {}                    # new row/col cannot pull in
    box["drive"] = HvDrive(35.0, hold_v=28.0)                    # hold below release: lets go
    assert _lit_after(clock, sim, 6, 7) == {}


def test_hold_drive_releases_sooner_by_the_discharge_time():
    rc = 1.0 * US
    tau_off = 0.9 * US / math.log(10)
    probe = 0.1 * US
    out = {}
    for name, drive in (("full", HvDrive(35.0)), ("hold", HvDrive(35.0, hold_v=30.0))):
        clock, sim, _ = _fpga(drive, rc_s=rc)
        _lit_after(clock, sim, 2, 3)
        _send(sim, p.Cmd.CLEAR)
        t_off = float(sim.drive_events()[2].max())  # the CLEAR's latch: lines go low
        r, c, tr = sim.lit_beams(t_off + probe, t_off + probe)
        out[name] = float(tr[0]) if tr.size else 0.0
    # release when the discharging drive crosses 29 V: rc*ln(V/29) after the latch (both switches)
    delay_full, delay_hold = rc * math.log(35 / 29), rc * math.log(30 / 29)
    assert delay_full > probe > delay_hold
    assert out["full"] == pytest.approx(1.0, abs=1e-9)
    single = math.exp(-(probe - delay_hold) / tau_off)
    assert out["hold"] == pytest.approx(single**2, rel=1e-6)   # row and column relax together


def test_threshold_spread_is_seeded_and_keeps_the_hysteresis_width():
    dyn = SwitchDynamics(1 * US, 1 * US, PULL_IN_V, RELEASE_V)
    a = switch_thresholds(4000, dyn, 0.5, [3, 1])
    b = switch_thresholds(4000, dyn, 0.5, [3, 1])
    c = switch_thresholds(4000, dyn, 0.5, [4, 1])
    np.testing.assert_array_equal(a[0], b[0])
    assert not np.array_equal(a[0], c[0])
    np.testing.assert_allclose(a[0] - a[1], PULL_IN_V - RELEASE_V)
    assert np.mean(a[0]) == pytest.approx(PULL_IN_V, abs=4 * 0.5 / math.sqrt(4000))
    assert np.std(a[0]) == pytest.approx(0.5, rel=0.05)
    np.testing.assert_array_equal(switch_thresholds(5, dyn, 0.0, 0)[0], np.full(5, PULL_IN_V))


def test_spread_decides_which_switches_pull_in_at_the_nominal_voltage():
    clock, sim, box = _fpga(HvDrive(PULL_IN_V), spread_v=0.5, seed=11)
    on = [bool(_lit_after(clock, sim, 0, c)) for c in range(20)]
    # the expected pattern from the seeded thresholds: a switch pulls in iff HV >= its pull-in
    rows_pull = switch_thresholds(20, sim.config.row_dynamics, 0.5, [11, 0x4B5, 0])[0]
    cols_pull = switch_thresholds(20, sim.config.col_dynamics, 0.5, [11, 0x4B5, 1])[0]
    assert on == [bool(rows_pull[0] <= PULL_IN_V and cp <= PULL_IN_V) for cp in cols_pull]
    assert 0 < sum(on) < 20
    assert not sim.pulls_in_every_switch()
    box["drive"] = HvDrive(PULL_IN_V + 5 * 0.5)
    assert sim.pulls_in_every_switch()


def _tap_readings(bench, hv_v: float) -> np.ndarray:
    """Emission-monitor level of one pixel per column (as the self-test reads it) at ``hv_v``."""
    model = bench.controller.model
    assert model.write(ctl_p.Table.HOLDING, ctl_p.HV_SETPOINT.address,
                       ctl_p.encode_value(ctl_p.HV_SETPOINT, hv_v)) is None
    assert model.write(ctl_p.Table.COIL, ctl_p.HV_ENABLE.address, [True]) is None
    bench.clock.advance(0.2)  # 40 HV time constants: the readback has settled
    _send(bench.fpga, p.Cmd.RESET)
    out = []
    for col in range(0, bench.profile.cols, 8):
        _send(bench.fpga, p.Cmd.SET_PIXEL, p.encode_set_pixel(bench.profile.bonded_rows[0], col))
        bench.clock.advance(20 * US)
        t = bench.clock.now()
        _, _, trans = bench.fpga.lit_beams(t, t)
        out.append(bench.tap_volts_per_beam() * float(trans.sum()))
    return np.array(out)


def test_controller_hv_reaches_the_fpga_and_the_selftest_names_it():
    bench = Bench(load_config(CONFIG_DIR / "sim.toml"))
    pr = bench.profile
    one_beam = bench.tap_volts_per_beam()
    low = pr.pull_in_v - 1.0
    dark = _tap_readings(bench, low)
    assert bench.fpga.supply().hv_v == pytest.approx(low, abs=1e-3)
    assert not bench.fpga.pulls_in_every_switch()
    assert np.all(dark < 0.01 * one_beam)                      # nothing pulled in
    msg = hv_pull_in_problem(dark, bench.controller.state.hv_v, pr.pull_in_v, dark_v=0.5 * one_beam,
                             spread_v=pr.threshold_spread_v)
    assert msg is not None and f"HV {low:.2f} V" in msg and f"{pr.pull_in_v:.2f} V" in msg
    assert f"{dark.size} of {dark.size}" in msg
    lit = _tap_readings(bench, pr.actuation_v)                  # the profile's drive: all on
    np.testing.assert_allclose(lit, one_beam, rtol=1e-6)
    assert hv_pull_in_problem(lit, bench.controller.state.hv_v, pr.pull_in_v, dark_v=0.5 * one_beam,
                              spread_v=pr.threshold_spread_v) is None


def test_selftest_hv_messages():
    assert hv_pull_in_problem([1.0, 1.0], 35.0, 32.0, dark_v=0.5) is None      # nothing dark
    assert hv_pull_in_problem([0.0, 1.0], 35.0, 32.0, dark_v=0.5) is None      # stuck switch, HV fine
    assert "within the pull-in spread" in hv_pull_in_problem([0.0, 1.0], 32.5, 32.0, dark_v=0.5,
                                                            spread_v=0.3)
    assert "below the switches' pull-in voltage 32.00 V" in hv_margin_problem(30.0, 32.0)
    assert hv_margin_problem(33.0, 32.0, 0.3) is None
    with pytest.raises(ValueError, match="hv_v"):
        hv_margin_problem(float("nan"), 32.0)
