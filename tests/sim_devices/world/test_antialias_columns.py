"""The anti-alias filter's column screen (sim_devices.world.antialias.column_rates): a bound on every
record sample's beat frequency from the chirp rates within its reach, so that only the samples near
a fast part of the chirp are examined -- with the same gains as examining every sample."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_laser
from lidard.physics.constants import C_M_PER_S
from sim_devices.digitizer.device import decimation_filter
from sim_devices.world import antialias
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import (
    AdcSpec, Effects, HitBatch, synthesize, trajectory, trajectory_from_frequency,
)

RAMP_S, EXC_HZ, FS_AWG = 80e-6, 8.6e9, 100e6


def _flyback():
    """A sawtooth chirp: 8.6 GHz up over 150 us, back in 10 us (15x the rate): a record's beat leaves
    the band only around the flyback."""
    up, back = int(150e-6 * FS_AWG), int(10e-6 * FS_AWG)
    nu = np.concatenate([np.linspace(0.0, EXC_HZ, up, endpoint=False), np.linspace(EXC_HZ, 0.0, back, endpoint=False)])
    return trajectory_from_frequency(nu, FS_AWG)


@pytest.fixture(scope="module", params=["ideal", "dfb_default", "flyback"])
def traj(request):
    if request.param == "flyback":
        return _flyback()
    laser = DfbLaser(load_laser(request.param))
    return trajectory(laser, triangle_drive(EXC_HZ, RAMP_S, FS_AWG, laser.static_tuning_hz_per_v), FS_AWG)


def _true_beat_hz(traj, x0, ratio, n, d_awg):
    """nu(X) - nu(X - d) at the record's samples X_k = x0 + k ratio, from the linearly interpolated
    frequency (the beat of a static return of delay d AWG samples)."""
    nu = traj.nu_hz

    def at(x):
        i = np.floor(x).astype(int)
        f = x - i
        return nu[i % nu.size] * (1 - f) + nu[(i + 1) % nu.size] * f

    x = x0 + np.arange(n) * ratio
    return at(x) - at(x - d_awg)


@pytest.mark.parametrize("fs, d_m", [(5e6, 1.5), (5e6, 30.0), (40e6, 2.0), (12.5e6, 7.0)])
def test_the_column_bound_holds_at_every_sample(traj, fs, d_m):
    n = int(round(2 * RAMP_S * fs))
    ratio = FS_AWG / fs
    tau = 2 * d_m / C_M_PER_S
    x0 = 3.0 * traj.n
    rates = antialias.column_rates(traj, x0, ratio, n, tau * FS_AWG)
    f = np.abs(_true_beat_hz(traj, x0, ratio, n, tau * FS_AWG))
    assert np.all(f <= tau * rates * (1 + 1e-9) + 1e-3)
    _, worst = antialias.trajectory_rates(traj)
    assert rates.max() <= worst


def test_the_bound_is_local():
    """Away from the flyback the bound is the ramp's rate, not the flyback's."""
    traj = _flyback()
    n, ratio = 800, FS_AWG / 5e6
    rates = antialias.column_rates(traj, 2.0 * traj.n, ratio, n, 20.0)
    ramp = EXC_HZ / 150e-6
    _, worst = antialias.trajectory_rates(traj)
    assert worst == pytest.approx(15 * ramp, rel=1e-3)
    assert np.mean(rates <= ramp * 1.001) > 0.85            # the flyback is 1/16 of the period


@pytest.mark.parametrize("fs, d_m, v, few", [(5e6, 1.8, 0.0, True), (5e6, 1.2, 0.3, True), (40e6, 3.5, 8.0, True),
                                             (5e6, 9.0, 0.0, False)])     # 9 m: the ramp's beat is out of band
def test_screened_gains_equal_the_full_computation(fs, d_m, v, few):
    """The synthesized records with the column screen equal those with every sample examined."""
    traj = _flyback()
    n = int(round(traj.period_s * fs))
    adc = AdcSpec(fs, n, bits=16, input_range_v=2.0, quantize=True)
    d = d_m + np.array([0.0, 0.013, 0.41, 1.3])
    hits = HitBatch.from_targets(np.arange(d.size), d, 0.3, radial_velocity_m_s=np.full(d.size, v))
    filt = decimation_filter(fs, 1e9, 60.0)
    assert filt is not None
    calls = []
    plain = antialias.sample_gains

    def spy(*a, cols=None, **kw):
        full = plain(*a, **kw)
        got = plain(*a, cols=cols, **kw)
        calls.append((cols, full, got))
        return got

    mp = pytest.MonkeyPatch()
    mp.setattr(antialias, "sample_gains", spy)
    try:
        synthesize(traj, adc, np.zeros(d.size), hits, effects=Effects(beat_filter=filt))
    finally:
        mp.undo()
    assert calls
    for cols, full, got in calls:
        assert cols is not None and (cols.size < n // 4) == few   # only a few columns examined
        assert full is not None                                 # the turning points leave the band
        for a, b in zip(full, got):
            assert np.array_equal(a, b)
