"""ChirpTrajectory: the phase is the integral of the frequency (differentiate and compare), periodic."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_laser
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import SynthError, trajectory, trajectory_from_frequency


@pytest.fixture(scope="module")
def dfb_traj():
    laser = DfbLaser(load_laser("dfb_default"))
    fs = 50e6
    return trajectory(laser, triangle_drive(8.6e9, 80e-6, fs, laser.static_tuning_hz_per_v), fs)


def test_phase_derivative_is_2_pi_times_the_frequency(dfb_traj):
    rng = np.random.default_rng(0)
    t = rng.uniform(0, 5 * dfb_traj.period_s, 2000)
    h = 0.1 / dfb_traj.fs_hz                        # inside one interpolation interval mostly
    dphase = (dfb_traj.phase_at(t + h) - dfb_traj.phase_at(t - h)) / (2 * h)
    nu = dfb_traj.frequency_at(t)
    # piecewise-linear nu: the central difference is exact except across a sample instant
    scale = np.ptp(dfb_traj.nu_hz)
    assert np.median(np.abs(dphase / (2 * np.pi) - nu)) < 1e-6 * scale
    assert np.max(np.abs(dphase / (2 * np.pi) - nu)) < 2e-3 * scale


def test_phase_grows_by_the_mean_frequency_each_period_and_matches_the_samples(dfb_traj):
    p = dfb_traj.period_s
    t = np.linspace(0, p, 777)
    grow = dfb_traj.phase_at(t + 3 * p) - dfb_traj.phase_at(t)
    assert np.allclose(grow, 2 * np.pi * dfb_traj.mean_hz * 3 * p, rtol=1e-9, atol=1e-6)
    k = np.arange(0, dfb_traj.n, 97)
    assert np.allclose(dfb_traj.phase_at(k / dfb_traj.fs_hz), dfb_traj.phase_rad[k], rtol=1e-12, atol=1e-6)
    assert dfb_traj.phase_rad.dtype == np.float64


def test_trapezoid_phase_of_a_linear_chirp_is_exact():
    fs = 10e6
    n = 1000
    gamma = 1e13
    nu = gamma * np.arange(n) / fs               # a sawtooth; only the first n-1 intervals are linear
    tr = trajectory_from_frequency(nu, fs)
    t = np.arange(n) / fs
    assert np.allclose(tr.phase_rad[:n], 2 * np.pi * gamma * t**2 / 2, rtol=1e-12, atol=1e-9)


def test_bad_trajectory_inputs():
    with pytest.raises(SynthError, match="nu_hz"):
        trajectory_from_frequency(np.array([1.0, np.inf]), 1e6)
    with pytest.raises(SynthError, match="fs_hz"):
        trajectory_from_frequency(np.zeros(4), -1.0)
    with pytest.raises(SynthError, match="dtype"):
        trajectory_from_frequency(np.zeros(4), 1e6, dtype=np.int32)
