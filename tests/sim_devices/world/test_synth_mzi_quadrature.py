"""The monitor MZI's quadrature output (issue 15: a second monitor channel for phase-noise compensation
at any range): sin where the monitor channel is cos, with the SAME phase noise, on request only."""

from __future__ import annotations

import numpy as np

from lidard.config import load_laser
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, MonitorMzi, synthesize, trajectory


def _traj():
    laser = DfbLaser(load_laser("ideal"))
    return trajectory(laser, triangle_drive(2e9, 80e-6, 100e6, laser.static_tuning_hz_per_v), 100e6)


def test_quadrature_channel_is_the_same_fringe_90_degrees_on_with_the_same_phase_noise():
    fs, n = 500e6, 4000
    adc = AdcSpec(fs, n, bits=16, input_range_v=4.0, quantize=False)
    hits = HitBatch.from_targets([0, 1], [30.0, 30.0], 0.2)
    eff = Effects(linewidth_hz=3e6)
    r = synthesize(_traj(), adc, np.zeros(2), hits, effects=eff, rng=np.random.default_rng(4),
                   mzi=MonitorMzi(200e-9, 0.3, quadrature=True))
    assert r.channels == ("beat", "mzi", "mzi_q")
    # I^2 + Q^2 = A^2 whatever the (noisy) phase: the two are one phasor
    np.testing.assert_allclose(r.mzi ** 2 + r.mzi_q ** 2, 0.3 ** 2, rtol=1e-9)
    # and its phase is the monitor channel's: the cos channel alone (same seed) is unchanged
    r1 = synthesize(_traj(), adc, np.zeros(2), hits, effects=eff, rng=np.random.default_rng(4),
                    mzi=MonitorMzi(200e-9, 0.3))
    np.testing.assert_array_equal(r1.mzi, r.mzi)
    assert r1.mzi_q is None and r1.channels == ("beat", "mzi")
