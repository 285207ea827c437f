"""The laser's true temperature and its chirp (issue 13, sim_devices.world.tec): carrier and FM response
follow dT as the formulas say, the chip's drift is the configured Ornstein-Uhlenbeck process, the TEC
readback does not show it, and a ``tec_offset`` step reaches the bench's chirp."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.controller import protocol as p
from lidard.config import CONFIG_DIR, load_config, load_laser
from sim_devices.bench.bench import Bench
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerModel
from sim_devices.faults import validate_fault
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import trajectory
from sim_devices.world.tec import QUANTUM_C, REFERENCE_C, TecDrift, TecTuning, from_tolerances
from tests.helpers.sim_bench import chirp_on

EXCURSION_HZ, RAMP_S, FS_HZ = 8.6e9, 80e-6, 50e6
MZI_S = 200e-9


def _beat_hz(traj, delay_s: float) -> np.ndarray:
    """Beat frequency nu(t) - nu(t - delay) of one period, from the trajectory's phase (what the MZI sees)."""
    n = traj.nu_hz.size
    k = int(round(delay_s * traj.fs_hz))
    phi = traj.phase_rad[:n]
    beat_phase = phi - np.roll(phi, k)
    return np.gradient(np.unwrap(beat_phase)) * traj.fs_hz / (2 * np.pi)


@pytest.mark.parametrize("dt_c", [-0.7, 0.2, 1.5])
def test_carrier_and_beat_frequency_follow_the_temperature(dt_c):
    tuning = TecTuning(tuning_hz_per_c=-12e9, response_per_c=0.002)
    base = DfbLaser(load_laser("dfb_default"))
    drive = triangle_drive(EXCURSION_HZ, RAMP_S, FS_HZ, base.static_tuning_hz_per_v)
    ref = trajectory(tuning.laser_at(base, REFERENCE_C), drive, FS_HZ)
    hot = trajectory(tuning.laser_at(base, REFERENCE_C + dt_c), drive, FS_HZ)
    # carrier: -12 GHz/C (a DFB warms to the red)
    assert hot.nu0_hz - ref.nu0_hz == pytest.approx(-12e9 * dt_c, rel=1e-9)
    # FM response x (1 + 0.002 dT): the MZI beat in the middle of the up ramp scales with it
    n_r = int(RAMP_S * FS_HZ)
    mid = slice(n_r // 4, 3 * n_r // 4)
    ratio = np.mean(_beat_hz(hot, MZI_S)[mid]) / np.mean(_beat_hz(ref, MZI_S)[mid])
    assert ratio == pytest.approx(1 + 0.002 * dt_c, abs=2e-6)


def test_drift_rms_and_correlation_time_match_the_configuration():
    rms_c, period_s = 0.05, 600.0
    d = TecDrift(rms_c, period_s, seed=(1, 2))
    t = np.arange(1, 3000 * 64) * d.step_s                   # 3000 correlation times on the grid
    x = np.array([d.at(ti) for ti in t[::4]])                # every 4th grid point
    assert np.sqrt(np.mean(x ** 2)) == pytest.approx(rms_c, rel=0.1)
    lag = 16                                                 # 16 x 4 grid steps = one period
    rho = np.dot(x[:-lag], x[lag:]) / np.dot(x, x)
    assert rho == pytest.approx(math.exp(-1.0), abs=0.06)
    # the correlation time itself, from the one-step correlation exp(-step / tau)
    rho1 = np.dot(x[:-1], x[1:]) / np.dot(x, x)
    assert -4 * d.step_s / math.log(rho1) == pytest.approx(period_s, rel=0.15)


def test_drift_starts_at_zero_and_does_not_depend_on_the_order_of_queries():
    a, b = TecDrift(0.1, 60.0, seed=7), TecDrift(0.1, 60.0, seed=7)
    assert a.at(0.0) == 0.0
    times = np.linspace(0.0, 2000.0, 301)
    forward = [a.at(t) for t in times]
    backward = [b.at(t) for t in times[::-1]][::-1]
    assert forward == backward
    assert TecDrift(0.1, 60.0, seed=8).at(1000.0) != forward[150]      # the seed matters


def test_tec_readback_shows_the_set_point_while_the_chip_drifts():
    clock = VirtualClock()
    drift = TecDrift(0.05, 600.0, seed=3)
    model = ControllerModel(clock, tec_drift=drift)
    clock.advance(900.0)
    words = model.image(p.Table.INPUT)
    readback = p.decode_value(p.TEC_TEMPERATURE, [words[p.TEC_TEMPERATURE.address]])
    assert readback == pytest.approx(25.0, abs=0.01)         # the thermistor, held at the set point
    assert model.laser_temperature_c() - 25.0 == pytest.approx(drift.at(900.0), abs=1e-12)
    assert abs(drift.at(900.0)) > 0.01                       # this seed drifted: the test can fail
    model.tec_offset_c = 0.2
    assert model.laser_temperature_c() - 25.0 == pytest.approx(drift.at(900.0) + 0.2, abs=1e-12)


@pytest.mark.tolerances   # the TEC model is part of [sim.tolerances]
def test_tolerances_section_drives_the_model():
    cfg = load_config(CONFIG_DIR / "sim.toml")
    tol = cfg.sim.tolerances
    tuning, drift = from_tolerances(tol, seed=1)
    assert tuning.tuning_hz_per_c == tol.tec_tuning_hz_per_c and tuning.response_per_c == tol.tec_response_per_c
    assert drift.rms_c == tol.tec_drift_c and drift.period_s == tol.tec_drift_period_s
    assert from_tolerances(tol.model_copy(update={"enabled": False}), seed=1) == (None, None)
    off = tol.model_copy(update={"tec_tuning_hz_per_c": 0.0, "tec_response_per_c": 0.0, "tec_drift_c": 0.0})
    assert from_tolerances(off, seed=1) == (None, None)


@pytest.mark.tolerances   # the TEC model is part of [sim.tolerances]
def test_a_tec_offset_step_reaches_the_benchs_chirp_and_the_cache_keys_on_temperature():
    bench = Bench(load_config(CONFIG_DIR / "sim.toml"))
    chirp_on(bench)
    bench.controller.model.tec_drift = None                  # only the step, for an exact comparison
    before = bench.synthesizer.trajectory()
    assert bench.synthesizer.trajectory() is before                     # same drive, same temperature: cached
    bench.inject_fault("tec_offset", offset_c=0.25)
    after = bench.synthesizer.trajectory()
    tol = bench.cfg.sim.tolerances
    assert after.nu0_hz - before.nu0_hz == pytest.approx(tol.tec_tuning_hz_per_c * 0.25, rel=1e-6)
    np.testing.assert_allclose(after.nu_hz, before.nu_hz * (1 + tol.tec_response_per_c * 0.25), rtol=1e-12,
                               atol=1e-6 * EXCURSION_HZ)
    bench.inject_fault("tec_offset", offset_c=0.25 + 0.3 * QUANTUM_C)     # below the 1 mK grid: reused
    assert bench.synthesizer.trajectory() is after
    assert bench.clear_faults("tec_offset") == 1
    np.testing.assert_allclose(bench.synthesizer.trajectory().nu_hz, before.nu_hz, rtol=0, atol=1e-6)


def test_tec_offset_fault_parameters_are_checked():
    assert validate_fault("tec_offset", {"offset_c": -0.5}) == {"kind": "tec_offset", "offset_c": -0.5}
    with pytest.raises(ValueError, match="tec_offset: parameter 'offset_c' is required"):
        validate_fault("tec_offset", {})
    with pytest.raises(ValueError, match=r"tec_offset: offset_c must be within \+-10 C, got 12"):
        validate_fault("tec_offset", {"offset_c": 12})
