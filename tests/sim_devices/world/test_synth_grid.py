"""The rational-grid fast path of the beat synthesis (sim_devices.world.synth_grid) against the
general path's per-sample evaluation of the same chirp phase, and end to end through synthesize."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_laser
from sim_devices.world import synth as synth_mod
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, synthesize, trajectory
from sim_devices.world.synth_grid import rational_ratio, static_beat_phase

RAMP_S = 80e-6
FS_AWG = 100e6


@pytest.fixture(scope="module")
def traj():
    laser = DfbLaser(load_laser("dfb_strong_nonlinear"))          # a real DFB: a nonlinear chirp, not a ramp
    return trajectory(laser, triangle_drive(8.6e9, RAMP_S, FS_AWG, laser.static_tuning_hz_per_v), FS_AWG)


@pytest.mark.parametrize("ratio, pq", [(2.5, (5, 2)), (100 / 120, (5, 6)), (4.0, (4, 1)), (1.25, (5, 4)),
                                       (100 / 7, (100, 7)), (100 / 17, None), (float("nan"), None), (0.0, None)])
def test_rational_ratio_is_exact_or_none(ratio, pq):
    assert rational_ratio(ratio) == pq
    if pq is not None:
        assert pq[0] / pq[1] == ratio


@pytest.mark.parametrize("fs_adc", [40e6, 120e6])
def test_static_phase_equals_the_general_paths_gathers(traj, fs_adc):
    """dPhi = P(b + r k) - P(b + r k - d) + const, evaluated per sample (three gathers) as the general
    path does, for delays across several AWG intervals (several delta groups) and exact integers."""
    n = 1200
    ratio = FS_AWG / fs_adc
    periods = 4
    off = float(traj.n)                              # one period back: every position >= 0
    rng = np.random.default_rng(3)
    d = np.concatenate([rng.uniform(0.0, 6.0, 40), [0.0, 1.0, 2.0, 3.0]])
    const = rng.uniform(-3.0, 3.0, d.size)
    k = np.arange(n)
    x = off + np.multiply.outer(np.ones(d.size), k * ratio) - d[:, None]
    expect = traj.periodic_phase_samples(off + k * ratio, periods) - traj._phase_nonneg(x, periods)
    expect += const[:, None]
    got = static_beat_phase(traj._tiled(periods), off, ratio, rational_ratio(ratio), n, d, const)
    assert np.max(np.abs(expect)) > 10.0             # a real beat phase, not a trivial zero
    assert np.max(np.abs(got - expect)) < 1e-8


def test_synthesize_gives_the_same_codes_with_and_without_the_fast_path(traj, monkeypatch):
    adc = AdcSpec(40e6, int(RAMP_S * 40e6), bits=16, input_range_v=1.0)
    hits = HitBatch.from_targets([0, 0, 1, 2, 4], [1.0, 2.3, 0.4, 7.9, 3.3], [0.2, 0.05, 0.3, 0.1, 0.2])
    t0 = np.zeros(5)
    fast = synthesize(traj, adc, t0, hits, effects=Effects(noise_asd_v_per_rthz=1e-8), rng=np.random.default_rng(1))
    monkeypatch.setattr(synth_mod, "rational_ratio", lambda ratio: None)
    slow = synthesize(traj, adc, t0, hits, effects=Effects(noise_asd_v_per_rthz=1e-8), rng=np.random.default_rng(1))
    diff = np.abs(fast.beat.astype(np.int32) - slow.beat)
    assert np.abs(slow.beat).max() > 1000             # the returns are there
    assert diff.max() <= 1 and np.count_nonzero(diff) <= 2     # ~1e-9 rad apart: a rounding tie at most
