"""Benchmark: laser phase-noise compensation from the monitor MZI (dissertation §2.3, Fig. 2-7).

Plain-numpy signals (one Wiener phase shared by LiDAR beat and monitor MZI, linear chirp at the
default rate, 20 us ramp, 1 GS/s, white noise on the beat), the shipped monitor delay
(lidard.config.Monitor().delay_s) and the known chirp rate. Per range (target at the nearest
M tau_m) and coherence time: detection probability without and with compensation (cell-averaging
threshold, Pfa ~ 1e-6 per cell), mean peak loss against a zero-linewidth laser with the same seed
(issue 3 target: within 3 dB), and the link-budget SNR of eq. 2-14..2-21 (lidard.physics.budget,
Table 2-2 set-up with that coherence time) for scale.
Run: python benchmarks/phase_noise.py
"""

from __future__ import annotations

import math

import numpy as np

from lidard.config import Monitor
from lidard.dsp.pncomp import compensated_spectrum
from lidard.physics.budget import LinkParams, snr_db

FS, RAMP_S, GAMMA = 1e9, 20e-6, 8.6e9 / 80e-6
C = 299_792_458.0
TAU_M = Monitor().delay_s


def _ramp(tau_s, lw, rng, noise_v, pn_seed):
    """Beat and MZI of one ramp; the phase noise comes from its own seed so that a zero-linewidth
    run with the same seed differs only by the phase noise."""
    n = int(RAMP_S * FS)
    d, dm = int(round(tau_s * FS)), int(round(TAU_M * FS))
    pre = d + dm + 10
    t = np.arange(-pre, n) / FS
    ph = np.pi * GAMMA * t ** 2
    if lw > 0:
        ph = ph + np.cumsum(np.random.default_rng(pn_seed).standard_normal(n + pre) * math.sqrt(2 * np.pi * lw / FS))
    beat = np.cos(ph[pre:] - ph[pre - d:pre - d + n] + 0.4) + noise_v * rng.standard_normal(n)
    mzi = 0.3 * np.cos(ph[pre:] - ph[pre - dm:pre - dm + n] + 1.1)
    return beat, mzi


def _peak(freq, spec, fb):
    i = int(np.argmin(np.abs(freq - fb)))
    return spec[i - 3:i + 4].max()


def _detected(freq, spec, fb):
    i = int(np.argmin(np.abs(freq - fb)))
    ref = np.concatenate([spec[i - 300:i - 30], spec[i + 30:i + 300]])
    return spec[i - 3:i + 4].max() ** 2 > np.mean(ref ** 2) * math.log(1e6)


def detection_curves(ranges_m, tau_c_s=(0.64e-6, 0.1e-6), trials: int = 20, seed: int = 1,
                     noise_v: float = 2.0) -> dict:
    """Pd raw/compensated and mean peak loss vs a zero-linewidth laser, per range per coherence time.

    Returns ``{"ranges_m": [...], "curves": [one dict per tau_c with lists over ranges_m: pd_raw,
    pd_comp, loss_raw_db, loss_comp_db (means), max_loss_comp_db, m, target_tau_s, snr_db], ...}``.
    """
    ranges_m = [float(d) for d in ranges_m]
    if not ranges_m or min(ranges_m) <= 0:
        raise ValueError(f"ranges_m must be positive distances, got {ranges_m!r}")
    rng = np.random.default_rng(seed)
    taus = [max(1, round(2 * d / C / TAU_M)) * TAU_M for d in ranges_m]
    max_delay_s = max(1.2e-6, max(taus) + TAU_M)
    kw = dict(fs_hz=FS, mzi_delay_s=TAU_M, max_delay_s=max_delay_s, chirp_rate_hz_per_s=GAMMA)
    out = {"ranges_m": ranges_m, "mzi_delay_s": TAU_M, "ramp_s": RAMP_S, "fs_hz": FS, "noise_v": noise_v,
           "trials": trials, "curves": []}
    for tau_c in tau_c_s:
        lw = 1.0 / (math.pi * tau_c)
        link = LinkParams.table_2_2(coherence_time_s=tau_c)
        c = {"tau_c_s": float(tau_c), "pd_raw": [], "pd_comp": [], "loss_raw_db": [], "loss_comp_db": [],
             "max_loss_comp_db": [], "m": [], "target_tau_s": [], "snr_db": []}
        for d_m, tau in zip(ranges_m, taus):
            fb = GAMMA * tau
            loss_raw, loss_comp, p_raw, p_comp = [], [], 0, 0
            for _ in range(trials):
                pn_seed = int(rng.integers(2 ** 31))
                noise_seed = int(rng.integers(2 ** 31))
                ref = compensated_spectrum(*_ramp(tau, 0.0, np.random.default_rng(noise_seed), 0.0, pn_seed), **kw)
                cs = compensated_spectrum(*_ramp(tau, lw, np.random.default_rng(noise_seed), noise_v, pn_seed), **kw)
                clean = compensated_spectrum(*_ramp(tau, lw, np.random.default_rng(noise_seed), 0.0, pn_seed), **kw)
                r0 = _peak(ref.freq_hz, ref.raw, fb)
                loss_raw.append(20 * math.log10(r0 / _peak(clean.freq_hz, clean.raw, fb)))
                loss_comp.append(20 * math.log10(r0 / _peak(clean.freq_hz, clean.comp, fb)))
                p_raw += _detected(cs.freq_hz, cs.raw, fb)
                p_comp += _detected(cs.freq_hz, cs.comp, fb)
            c["pd_raw"].append(p_raw / trials)
            c["pd_comp"].append(p_comp / trials)
            c["loss_raw_db"].append(float(np.mean(loss_raw)))
            c["loss_comp_db"].append(float(np.mean(loss_comp)))
            c["max_loss_comp_db"].append(float(np.max(loss_comp)))
            c["m"].append(int(round(tau / TAU_M)))
            c["target_tau_s"].append(tau)
            c["snr_db"].append(float(snr_db(link, d_m)))
        out["curves"].append(c)
    return out


def main(ranges_m=(15.0, 30.0, 50.0, 75.0, 100.0, 150.0, 200.0), trials=20):
    r = detection_curves(ranges_m, trials=trials)
    print(f"phase-noise compensation: monitor tau_m {TAU_M * 1e9:.0f} ns (shipped), {trials} trials, "
          f"beat noise {r['noise_v']} V rms on a 1 V beat; peak loss vs zero linewidth (target <= 3 dB)")
    print(f"{'tau_c us':>8s} {'range m':>7s} {'M':>3s} {'loss raw dB':>11s} {'loss comp dB (max)':>19s} "
          f"{'Pd raw':>6s} {'Pd comp':>7s} {'budget SNR dB':>13s}")
    for c in r["curves"]:
        for j, d in enumerate(r["ranges_m"]):
            print(f"{c['tau_c_s'] * 1e6:8.2f} {d:7.0f} {c['m'][j]:3d} {c['loss_raw_db'][j]:11.1f} "
                  f"{c['loss_comp_db'][j]:11.1f} ({c['max_loss_comp_db'][j]:4.1f}) {c['pd_raw'][j]:6.2f} "
                  f"{c['pd_comp'][j]:7.2f} {c['snr_db'][j]:13.1f}")


if __name__ == "__main__":
    main()
