"""Quadrature monitor on a triangle chirp (issue 15): on the falling ramp the fringe I + jQ turns
backwards while the analytic signal of the real beat always turns forwards (the laser phase enters it
with the opposite sign); the frame DSP must range a far, off-grid target from both ramps.

Signals from the definitions (Wiener laser phase, Var[phi(t) - phi(t - tau)] = 2 pi linewidth tau,
eq. 2-9; rising ramp phase +pi gamma t^2, falling -pi gamma t^2), not from the code under test.
"""

import math

import numpy as np

from lidard.dsp.frame import FrameDsp

C = 299_792_458.0
FS = 500e6
GAMMA = 8.6e9 / 80e-6
TAU_M = 200e-9
N = 12_000
RANGE_M = 103.0                           # off the 200 ns (30 m) grid: 3.44 delays


def _ramp(lw, seed, sign):
    tau = 2 * RANGE_M / C
    pre = int(math.ceil(tau * FS)) + 4
    t = np.arange(-pre, N) / FS
    ph = sign * np.pi * GAMMA * t ** 2
    ph = ph + np.cumsum(np.random.default_rng(seed).standard_normal(N + pre) * math.sqrt(2 * np.pi * lw / FS))
    k, grid = np.arange(N) + pre, np.arange(N + pre)
    beat = np.cos(ph[pre:] - np.interp(k - tau * FS, grid, ph) + 0.4)
    beat += 0.3 * np.random.default_rng(seed + 1).standard_normal(N)
    d = int(round(TAU_M * FS))
    th = ph[pre:] - ph[pre - d:pre - d + N] + 1.1
    return beat, 0.3 * np.cos(th), 0.3 * np.sin(th)


def test_a_far_off_grid_target_is_ranged_from_the_rising_and_the_falling_ramp():
    lw = 1.0 / (math.pi * 0.1e-6)                      # tau_c = 0.1 us: 2 tau / tau_c = 14
    dsp = FrameDsp(ramp_samples=N, fs_hz=FS, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6,
                   max_range_m=120.0, min_range_m=1.0, max_speed_mps=0.4, use_fraction=0.7)
    recs = [[np.concatenate(parts) for parts in zip(_ramp(lw, 10 + s, 1), _ramp(lw, 50 + s, -1))]
            for s in range(4 * 2)]
    beat, mi, mq = (np.reshape(np.array([r[j] for r in recs]), (4, 2, 2 * N)) for j in range(3))
    res = dsp.process(beat, mzi=mi, mzi_q=mq, mzi_delay_s=TAU_M)
    assert res.present.any(axis=1).all()               # pairing needs both ramps' detections
    assert np.all(np.abs(res.range_m[res.present] - RANGE_M) < 0.3)
