"""A weak return beside a much stronger one in the same beam, far apart or at twice its range: the
frame DSP's range error against the same weak return alone in the same noise and against its
Cramer-Rao bound, and how often it is flagged (docs/measured/25_far_pairs.md).

    python benchmarks/far_pairs.py [--pixels 300] [--json]

Pixels from the tone model (lidard.dsp.ranging.lines): one record each, a strong static return at
1.0-1.5 m and a weak one 20 dB under it at 1.37x, 1.5x or exactly 2x its range (2x: where a harmonic of
the strong one would beat), white noise set by the strong one's post-FFT SNR, through a triangle
FrameDsp (5 MS/s, 400-sample ramps, 3.2 m gate). Columns: the weak return's RMS range error in the pair,
alone, and its one-tone bound (both ramps averaged); how many of its pixels gave a valid point; how
many were flagged unresolved (bit 1) or harmonic (bit 4). The ``--sfdr`` column repeats the pair with
the harmonic screen at the former 15 dB level. No hardware, no bench: seconds of CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from dataclasses import replace

import numpy as np

from lidard.dsp.detect.gate import PointFlag
from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.crlb import crlb_freq_var
from lidard.dsp.ranging.lines import lines, render
from lidard.dsp.spectrum.rangefft import C_M_PER_S

GAMMA = 8.6e9 / 80e-6
DSP = FrameDsp(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6,
               max_range_m=3.2, max_speed_mps=0.4)
WEAK_AMP = 0.1          # 20 dB under the strong return


def _points(dsp: FrameDsp, ranges_m: np.ndarray, amps: np.ndarray, snr_db: float, seed: int):
    rng = np.random.default_rng(seed)
    ln = lines(ranges_m, np.zeros_like(ranges_m), chirp_rate_hz_per_s=GAMMA, wavelength_m=dsp.wavelength_m)
    x = render(ln, amps, rng.uniform(0, 2 * np.pi, ranges_m.shape + (3,)), fs_hz=dsp.fs_hz,
               ramp_samples=dsp.ramp_samples, cw_samples=0)
    sigma = np.sqrt(dsp.n_used / (4 * 10 ** (snr_db / 10)))
    return dsp.process((x + sigma * rng.standard_normal(x.shape))[:, None, :]), sigma


def _weak(res, truth_m: np.ndarray, tol_m: float = 5e-3):
    hit = res.present & (np.abs(res.range_m - truth_m[:, None]) < tol_m)
    err = np.nanmax(np.where(hit & res.valid, res.range_m - truth_m[:, None], np.nan), axis=1)
    flags = np.bitwise_or.reduce(np.where(hit, res.flags, 0), axis=1)
    return err, flags


def row(snr_db: float, ratio: float, pixels: int) -> dict:
    d = np.random.default_rng(3).uniform(1.0, 1.5, pixels)
    weak_m = ratio * d
    pair_r, pair_a = np.stack([d, weak_m], axis=1), np.tile([1.0, WEAK_AMP], (pixels, 1))
    res, sigma = _points(DSP, pair_r, pair_a, snr_db, seed=4)
    alone, _ = _points(DSP, weak_m[:, None], np.full((pixels, 1), WEAK_AMP), snr_db, seed=4)
    old, _ = _points(replace(DSP, sfdr_dbc=15.0), pair_r, pair_a, snr_db, seed=4)
    e_pair, f_pair = _weak(res, weak_m)
    e_alone, _ = _weak(alone, weak_m)
    _, f_old = _weak(old, weak_m)
    snr = WEAK_AMP ** 2 / (2 * sigma ** 2)
    bound = C_M_PER_S / (2 * GAMMA) * np.sqrt(crlb_freq_var(snr, DSP.n_used, real=True, fs_hz=DSP.fs_hz) / 2)

    def rms(e: np.ndarray) -> float:
        return float(np.sqrt(np.nanmean(e ** 2))) if np.isfinite(e).any() else float("nan")

    return {"strong_snr_db": snr_db, "weak_at_x_range": ratio,
            "separation_bins": float(np.median((ratio - 1) * d) / DSP.range_resolution_m),
            "rms_pair_um": rms(e_pair) * 1e6, "rms_alone_um": rms(e_alone) * 1e6, "crlb_um": bound * 1e6,
            "valid_pair": int(np.isfinite(e_pair).sum()), "valid_alone": int(np.isfinite(e_alone).sum()),
            "unresolved": int(np.count_nonzero(f_pair & PointFlag.UNRESOLVED)),
            "harmonic": int(np.count_nonzero(f_pair & PointFlag.HARMONIC)),
            "harmonic_at_15_db": int(np.count_nonzero(f_old & PointFlag.HARMONIC)), "pixels": pixels}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pixels", type=int, default=300)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    rows = [row(s, r, a.pixels) for s in (45.0, 55.0, 65.0) for r in (1.37, 1.5, 2.0)]
    if a.json:
        print(json.dumps({"machine": f"{platform.machine()}, {os.cpu_count()} cores", "rows": rows}))
        return
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")
    print("| strong SNR (dB) | weak at | apart (bins) | weak RMS in the pair (um) | alone (um) | bound (um) "
          "| valid pair / alone | unresolved | harmonic (sfdr 40 dBc) | harmonic at the former 15 dB |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['strong_snr_db']:.0f} | {r['weak_at_x_range']:.2f}x | {r['separation_bins']:.0f} "
              f"| {r['rms_pair_um']:.1f} | {r['rms_alone_um']:.1f} | {r['crlb_um']:.1f} "
              f"| {r['valid_pair']} / {r['valid_alone']} of {r['pixels']} | {r['unresolved']} | {r['harmonic']} "
              f"| {r['harmonic_at_15_db']} |")


if __name__ == "__main__":
    main()
