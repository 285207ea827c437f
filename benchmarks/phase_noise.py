"""Benchmark: laser phase-noise compensation from the monitor MZI (dissertation §2.3, Fig. 2-7).

Plain-numpy signals (one Wiener phase shared by LiDAR beat and monitor MZI, linear chirp at the
default rate, 20 us ramp, 1 GS/s, white noise on the beat), the shipped monitor delay
(lidard.config.Monitor().delay_s) and the known chirp rate. Per range (target at the nearest
M tau_m) and coherence time: detection probability without and with compensation (cell-averaging
threshold, Pfa ~ 1e-6 per cell), mean peak loss against a zero-linewidth laser with the same seed
(issue 3 target: within 3 dB), and the link-budget SNR of eq. 2-14..2-21 (lidard.physics.budget,
Table 2-2 set-up with that coherence time) for scale.

The any-range sweep (:func:`loss_sweep`, issue 15): the target at its TRUE range (15-200 m, 1 m steps,
fractional-sample delay), the monitor channel with its own noise (shot + RIN lumped as white noise,
then the 8-bit ADC's quantization), mean and worst peak loss against a zero-linewidth laser for
three monitor set-ups: ``grid`` (one real MZI of 200 ns, the dissertation's: nearest multiple M),
``short`` (one real MZI of 20 ns << tau_c, summed the same way: option "short MZI"), ``quadrature``
(the 200 ns MZI read in quadrature, laser phase rebuilt per sample, lidard.dsp.phasenoise.reconstruct).
Run: python benchmarks/phase_noise.py [--sweep]
"""

from __future__ import annotations

import math

import numpy as np
from scipy.signal import get_window, hilbert

from lidard.config import Monitor
from lidard.dsp.phasenoise.compensate import compensated_spectrum
from lidard.dsp.phasenoise.reconstruct import delayed, quadrature_delta, reconstruct_phase
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


# monitor channel: 0.3 V fringe (lidard.config.Monitor), 2 mV rms white (shot + RIN), 8-bit ADC on +-1 V
MON_AMP_V, MON_NOISE_V, MON_BITS, MON_FS_V = Monitor().amplitude_v, 2e-3, 8, 1.0
SHORT_DELAY_S = 20e-9
METHODS = ("grid", "short", "quadrature")


def _record(tau_s, lw, pn_seed, mon_seed, delay_s):
    """Beat (noise-free: the loss is a phase-noise figure) and the noisy, quantized monitor I and Q
    (Q = the quadrature output of the same MZI) for a target at the true round trip ``tau_s``."""
    n = int(RAMP_S * FS)
    pre = int(math.ceil(max(tau_s, delay_s) * FS)) + 4
    t = np.arange(-pre, n) / FS
    ph = np.pi * GAMMA * t ** 2
    if lw > 0:
        ph = ph + np.cumsum(np.random.default_rng(pn_seed).standard_normal(n + pre) * math.sqrt(2 * np.pi * lw / FS))
    k = np.arange(n) + pre
    grid = np.arange(n + pre)
    beat = np.cos(ph[pre:] - np.interp(k - tau_s * FS, grid, ph) + 0.4)
    th = ph[pre:] - np.interp(k - delay_s * FS, grid, ph) + 1.1
    rng = np.random.default_rng(mon_seed)
    lsb = 2 * MON_FS_V / 2 ** MON_BITS
    i, q = (np.round((MON_AMP_V * f(th) + MON_NOISE_V * rng.standard_normal(n)) / lsb) * lsb for f in (np.cos, np.sin))
    return beat, i, q


def _peak_loss(tau_s, lw, pn_seed, mon_seed, method, max_delay_s):
    """Compensated peak (|FFT| max within +-3 bins of the beat), zero linewidth over ``lw``, in dB."""
    delay = SHORT_DELAY_S if method == "short" else TAU_M
    kw = dict(fs_hz=FS, mzi_delay_s=delay, max_delay_s=max_delay_s, chirp_rate_hz_per_s=GAMMA)
    peaks = []
    for width in (0.0, lw):
        beat, i, q = _record(tau_s, width, pn_seed, mon_seed, delay)
        if method != "quadrature":
            cs = compensated_spectrum(beat, i, **kw)
            peaks.append(_peak(cs.freq_hz, cs.comp, GAMMA * tau_s))
            continue
        # compensated_spectrum(beat, i, mzi_q=q) computes every bin's step; only the target's are needed
        # here (tests check that the two agree)
        n_edge, step = int(math.ceil(max(20.0 / FS, 1e-6) * FS)), TAU_M / 16
        start = n_edge + int(math.ceil(math.ceil(max_delay_s / TAU_M - 1e-9) * TAU_M * FS))
        stop = beat.size - n_edge
        valid = np.zeros(beat.size, dtype=bool)
        valid[n_edge:stop] = True
        phi, _ = reconstruct_phase(quadrature_delta(i, q, fs_hz=FS, beat_hz=GAMMA * TAU_M), valid, round(TAU_M * FS))
        z = hilbert(beat - beat.mean())[start:stop]
        e = phi[start:stop] - delayed(phi, round(tau_s / step) * step * FS)[start:stop]
        spec = np.abs(np.fft.fft(z * np.exp(-1j * e) * get_window("hann", stop - start, fftbins=False)))
        peaks.append(_peak(np.fft.fftfreq(stop - start, 1 / FS), spec, GAMMA * tau_s))
    return 20 * math.log10(peaks[0] / peaks[1])


def loss_sweep(ranges_m, tau_c_s=(0.1e-6, 0.64e-6), methods=METHODS, trials: int = 4, seed: int = 3) -> dict:
    """Mean and worst compensated peak loss (dB) against zero linewidth at the TRUE ranges ``ranges_m``.

    Returns ``{"ranges_m", "trials", "curves": [{"tau_c_s", "method", "mean_db": [...], "max_db": [...],
    "worst_mean_db", "worst_mean_at_m"}]}``.
    """
    ranges_m = [float(d) for d in ranges_m]
    if not ranges_m or min(ranges_m) <= 0:
        raise ValueError(f"ranges_m must be positive distances, got {ranges_m!r}")
    max_delay = 2 * max(ranges_m) / C + 10e-9
    out = {"ranges_m": ranges_m, "trials": trials, "monitor_noise_v": MON_NOISE_V, "monitor_bits": MON_BITS,
           "short_delay_s": SHORT_DELAY_S, "mzi_delay_s": TAU_M, "curves": []}
    for tau_c in tau_c_s:
        lw = 1.0 / (math.pi * tau_c)
        for method in methods:
            rng = np.random.default_rng(seed)
            mean, worst = [], []
            for d in ranges_m:
                ls = [_peak_loss(2 * d / C, lw, int(rng.integers(2 ** 31)), int(rng.integers(2 ** 31)), method, max_delay)
                      for _ in range(trials)]
                mean.append(float(np.mean(ls)))
                worst.append(float(np.max(ls)))
            j = int(np.argmax(mean))
            out["curves"].append({"tau_c_s": float(tau_c), "method": method, "mean_db": mean, "max_db": worst,
                                  "worst_mean_db": mean[j], "worst_mean_at_m": ranges_m[j]})
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


def main_sweep(step_m: float = 1.0, trials: int = 4):
    r = loss_sweep(np.arange(15.0, 200.0 + 1e-9, step_m), trials=trials)
    print(f"any-range sweep 15-200 m step {step_m} m, {trials} trials; monitor {MON_NOISE_V * 1e3:.0f} mV rms + "
          f"{MON_BITS}-bit ADC; worst mean peak loss vs zero linewidth (target <= 3 dB)")
    for c in r["curves"]:
        print(f"  tau_c {c['tau_c_s'] * 1e6:.2f} us {c['method']:>10s}: worst mean {c['worst_mean_db']:5.2f} dB "
              f"at {c['worst_mean_at_m']:.0f} m, worst single {max(c['max_db']):5.2f} dB")
    return r


if __name__ == "__main__":
    import sys
    main_sweep() if "--sweep" in sys.argv else main()
