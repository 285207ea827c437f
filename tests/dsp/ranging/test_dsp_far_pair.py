"""A weak return beside a much stronger one far from it in the same beam (a dark wall behind a bright
pane, an edge pixel that sees a bright object and the room behind it): each record holds both tones,
so the weak one's estimate must not read the strong one's leakage. Pixels from the tone model
(lidard.dsp.ranging.lines), one record each, through the frame DSP, against the same weak return
alone in the same noise and against its Cramer-Rao bound."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.detect.gate import PointFlag
from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.crlb import crlb_freq_var
from lidard.dsp.ranging.lines import lines, render
from lidard.dsp.spectrum.rangefft import C_M_PER_S

GAMMA = 8.6e9 / 80e-6
DSP = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6,
               max_range_m=3.2, max_speed_mps=0.4)
N_PIX = 150


def _scan(ranges_m, amps, strong_snr_db, seed):
    """The frame DSP's points of pixels holding these static returns, noise set by the strongest's
    post-FFT SNR (rectangular, on-bin: N A^2 / 4 sigma^2), and the noise sigma."""
    rng = np.random.default_rng(seed)
    r = np.asarray(ranges_m, dtype=float)
    ln = lines(r, np.zeros_like(r), chirp_rate_hz_per_s=GAMMA, wavelength_m=DSP.wavelength_m)
    x = render(ln, np.asarray(amps, dtype=float), rng.uniform(0, 2 * np.pi, r.shape + (3,)), fs_hz=DSP.fs_hz,
               ramp_samples=DSP.ramp_samples, cw_samples=0)
    sigma = np.sqrt(DSP.n_used / (4 * 10 ** (strong_snr_db / 10)))
    return DSP.process((x + sigma * rng.standard_normal(x.shape))[:, None, :]), sigma


def _on(res, truth_m, tol_m=5e-3):
    """Per pixel: the error of the point on the surface at ``truth_m`` (NaN if none) and its flags."""
    hit = res.present & (np.abs(res.range_m - truth_m[:, None]) < tol_m)
    err = np.nanmax(np.where(hit, res.range_m - truth_m[:, None], np.nan), axis=1)
    return err, np.bitwise_or.reduce(np.where(hit, res.flags, 0), axis=1)


@pytest.mark.parametrize("strong_snr_db", [55.0, 65.0])
@pytest.mark.parametrize("ratio", [1.37, 1.5])
def test_a_weak_return_far_from_a_strong_one_is_as_good_as_alone(strong_snr_db, ratio):
    # the weak return 20 dB under the strong one, 20-30 range bins behind it (a bin: c / 2 gamma T)
    d = np.random.default_rng(3).uniform(1.0, 1.5, N_PIX)
    weak_m, amp = ratio * d, 0.1
    pair, sigma = _scan(np.stack([d, weak_m], axis=1), np.tile([1.0, amp], (N_PIX, 1)), strong_snr_db, seed=4)
    alone, _ = _scan(weak_m[:, None], np.full((N_PIX, 1), amp), strong_snr_db, seed=4)   # same noise level
    err_pair, flags_pair = _on(pair, weak_m)
    err_alone, _ = _on(alone, weak_m)
    assert np.isfinite(err_pair).all() and np.isfinite(err_alone).all()
    rms_pair, rms_alone = np.sqrt(np.mean(err_pair ** 2)), np.sqrt(np.mean(err_alone ** 2))
    # the bound on one return's range (a real tone's frequency, both ramps averaged)
    snr = amp ** 2 / (2 * sigma ** 2)
    bound = C_M_PER_S / (2 * GAMMA) * np.sqrt(crlb_freq_var(snr, DSP.n_used, real=True, fs_hz=DSP.fs_hz) / 2)
    # before the joint fit the pair's weak return was 10-15x its alone error (0.2-0.3 mm at 55-65 dB)
    assert rms_pair < 1.3 * rms_alone, (rms_pair, rms_alone)
    assert rms_pair < 2.5 * bound, (rms_pair, bound)       # Hann's loss against the bound included
    # and its model-order test reads what is there: at most the stated rate flagged (order_level 1e-3
    # per ramp; 2 in 150 allows the Poisson tail)
    assert np.count_nonzero(flags_pair & PointFlag.UNRESOLVED) <= 2
    assert abs(np.mean(err_pair)) < 4 * rms_pair / np.sqrt(N_PIX)       # no bias beyond the scatter
