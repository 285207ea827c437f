"""Chirp measurement for the ILC from a quadrature monitor MZI (dissertation §2.2).

The real MZI beat of :mod:`lidard.dsp.linearize.ilc` is averaged coherently over records before its phase is
taken: with a broad linewidth on a long MZI (tau_m = 2 tau_c for dfb_broad_linewidth) the averaged
fringe shrinks by exp(-pi linewidth tau_m) (x0.14) while the noise does not, which sets the noise
floor that stopped linearization at ~400x. A quadrature monitor (I + jQ, the same MZI read through a
90-degree hybrid or 3x3 coupler, :mod:`lidard.dsp.phasenoise.reconstruct`) gives every record's phase directly:
here the phases are averaged, not the fringes, so nothing shrinks and the laser's frequency noise
falls as 1 / sqrt(records). The phase's sign is physical (no Hilbert fold at the turning points).

The MZI phase is theta(t) = 2 pi int_{t - tau_m}^{t} nu = 2 pi tau_m nu(t) + const for the slow
chirp nonlinearity the ILC learns, so nu = theta / (2 pi tau_m), expressed in the drive frame of
:mod:`lidard.dsp.linearize.ilc` (multiplied by the sign of the tuning, so that the plant gain is positive).

Pure numpy: no I/O, no clock, no logging.
"""

from __future__ import annotations

import math

import numpy as np

from ..spectrum.instfreq import lowpass_padded


def quadrature_ramp_nu(y: np.ndarray, *, fs_hz: float, ramp_s: float, mzi_delay_s: float, edge_s: float,
                       directions: tuple[int, int], meas_cutoff_hz: float) -> list[tuple[np.ndarray, np.ndarray, int]]:
    """Per ramp (first, second half of the period): (t_s, drive-frame nu_hz low-passed, 0 slips).

    ``y``: (records, 2 ramp_s fs_hz) complex I + jQ of the monitor, each record aligned with the drive
    period. Times are those of the samples at least ``edge_s`` from either end of the ramp.
    """
    z = np.asarray(y, dtype=np.complex128)
    n_r = z.shape[-1] // 2
    n_edge = max(1, int(math.ceil(edge_s * fs_hz)))
    k = np.arange(n_edge, n_r - n_edge)
    thetas = []
    for r in range(2):
        seg = z[:, r * n_r:(r + 1) * n_r]
        seg = seg - seg.mean(axis=-1, keepdims=True)          # photodiode and ADC offsets
        seg = seg[:, n_edge:n_r - n_edge]
        # the fringe's mean frequency (lag-1 products of all records: slips cannot bias it), removed
        # before unwrapping so that the per-sample step is only the noise and the nonlinearity
        w = float(np.angle(np.sum(seg[:, 1:] * np.conj(seg[:, :-1]))))
        ramp = np.exp(-1j * w * np.arange(seg.shape[-1]))
        th = np.unwrap(np.angle(seg * ramp), axis=-1)
        th -= th.mean(axis=-1, keepdims=True)                   # each record's own fringe phase
        thetas.append(th.mean(axis=0) + w * np.arange(seg.shape[-1]))
    # the tuning's sign: the MZI phase rises on the ramp where the optical frequency rises
    sign = 1.0 if (thetas[0][-1] - thetas[0][0]) * directions[0] >= 0 else -1.0
    out = []
    for r in range(2):
        nu = sign * thetas[r] / (2 * np.pi * mzi_delay_s)
        out.append((r * ramp_s + k / fs_hz, lowpass_padded(nu, fs_hz, meas_cutoff_hz), 0))
    return out
