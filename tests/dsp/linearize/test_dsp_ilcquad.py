"""ILC measurement from a quadrature monitor (lidard.dsp.linearize.quadrature; §2.2, issue 15): per-record phases
averaged, nu = theta / (2 pi tau_m) in the drive frame. Records built here from the definition
theta(t) = 2 pi int_{t - tau_m}^{t} nu, with random per-record fringe phases and white phase noise."""

import numpy as np

from lidard.dsp.linearize.quadrature import quadrature_ramp_nu

FS, T, TAU = 100e6, 80e-6, 200e-9
SLOPE = 8.6e9 / 80e-6


def _records(n_rec, bow_hz, seed, tuning_sign=1.0):
    n = int(2 * T * FS)
    t = np.arange(n) / FS
    tri = np.where(t < T, SLOPE * t, SLOPE * (2 * T - t))          # drive-frame nu, up then down
    nu = tuning_sign * (tri + bow_hz * np.sin(2 * np.pi * t / T))   # optical frequency
    # theta = 2 pi int_{t - tau}^{t} nu: the cumulative integral on the sample grid
    cum = np.cumsum(nu) / FS
    d = int(TAU * FS)
    theta = 2 * np.pi * (cum - np.concatenate([np.zeros(d), cum[:n - d]]))   # first tau_m: in the edge
    rng = np.random.default_rng(seed)
    z = np.exp(1j * (theta[None, :] + rng.uniform(0, 2 * np.pi, (n_rec, 1))
                     + 0.2 * rng.standard_normal((n_rec, n))))
    return z, t, tri, bow_hz * np.sin(2 * np.pi * t / T)


def test_bow_of_the_chirp_is_recovered_in_the_drive_frame_for_either_tuning_sign():
    for sign in (1.0, -1.0):
        z, t, tri, bow = _records(16, 2e6, seed=3, tuning_sign=sign)
        out = quadrature_ramp_nu(z, fs_hz=FS, ramp_s=T, mzi_delay_s=TAU, edge_s=2e-6, directions=(1, -1),
                                 meas_cutoff_hz=1e6)
        for r, (tr, nu, slips) in enumerate(out):
            k = np.rint(tr * FS).astype(int)
            # drive frame: the plant gain is positive, so nu follows +tri + bow whatever the sign
            expect = tri[k] + bow[k]
            resid = (nu - nu.mean()) - (expect - expect.mean())
            sl = slice(100, -100)          # the low-pass's padded ends
            # (the MZI averages nu over tau_m: the bow is seen tau_m / 2 late, ~16 kHz here)
            assert np.sqrt(np.mean(resid[sl] ** 2)) < 0.02 * 2e6, (sign, r)
            assert slips == 0
