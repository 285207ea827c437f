"""Benchmark: OS-CFAR on spectra averaged over K records, with the Gamma(K) noise model (lidard.dsp.detect.os_gamma)
against the exponential one it replaced (Rohling's factor whatever K).

Pixels drawn from the tone model (lidard.dsp.ranging.lines) on the scan's default chirp (benchmarks/
resolution_table.py's: three-segment, 40 MS/s, 3200-sample ramps, 10 m gate) with K records a pixel,
through the scan's FrameDsp ("before": the same code with the detector's constants forced to K = 1,
i.e. the exponential model).

(a) noise-only pixels at K = 1, 4, 10: the per-ramp detector's alarms per ramp cell of the gate
    against its level q (FrameDsp.ramp_pfa), and the valid false points per gate cell against ``pfa``;
(b) one static return at 5 m, K = 10, the default pfa (1e-11): the fraction of pixels with a valid
    point within half a range cell of the truth against the per-record SNR (one ramp's post-FFT SNR,
    rectangular window, on-bin: N A^2 / (4 sigma^2)).

Run: python benchmarks/cfar_averages.py [--pixels 2000] [--pd-pixels 300] [--out docs/measured/27_cfar_averages.md]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from resolution_table import CELL_M, CW, FS_HZ, RAMP, RATE, WAVELENGTH, scan_dsp

from lidard.dsp.detect import os_cfar
from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.lines import lines, render

KS = (1, 4, 10)
NOISE_PFA = 1e-5          # false points per range cell: a per-ramp level q = 1e-3 (m = 10), enough alarms to count
SNRS_DB = (2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0, 16.0, 18.0, 20.0, 22.0)
PD_K = 10
R0_M = 5.0


@contextlib.contextmanager
def exponential_model() -> Iterator[None]:
    """The detector as it was: alpha and the noise scale of exponential cells whatever K."""
    real = os_cfar._os_constants

    def as_one(n_ref_side: int, pfa: float, rank: int | None, records: int = 1) -> tuple[int, float, float, float]:
        return real(n_ref_side, pfa, rank, 1)

    os_cfar._os_constants = as_one    # type: ignore[assignment]
    try:
        yield
    finally:
        os_cfar._os_constants = real   # type: ignore[assignment]


def noise_only(dsp: FrameDsp, k: int, n_pix: int, seed: int) -> tuple[int, int, int]:
    """(per-ramp alarms, valid false points, gate cells) over ``n_pix`` noise-only pixels of ``k`` records."""
    rng = np.random.default_rng(seed)
    lo, hi = dsp.bin_range
    alarms = valid = 0
    done = 0
    while done < n_pix:
        m = min(max(1, 4000 // k), n_pix - done)
        x = rng.standard_normal((m, k, 2 * RAMP + CW))
        res = dsp.process(x)
        _, dets = dsp._plain_front_end(x, 1.0)
        alarms += sum(int(np.count_nonzero(d.valid)) for d in dets)
        valid += int(np.count_nonzero(res.present & res.valid))
        done += m
    return alarms, valid, (hi - lo + 1) * n_pix


def pd(dsp: FrameDsp, snr_db: float, n_pix: int, seed: int) -> float:
    """The fraction of pixels (``PD_K`` records each, random phase per record) with a valid point within
    half a range cell of the return at R0_M."""
    rng = np.random.default_rng(seed)
    ln = lines(np.array([R0_M]), np.array([0.0]), chirp_rate_hz_per_s=RATE, wavelength_m=WAVELENGTH)
    sigma = np.sqrt(dsp.n_used / (4 * 10 ** (snr_db / 10)))
    hit = 0
    for p0 in range(0, n_pix, 200):
        m = min(200, n_pix - p0)
        ph = rng.uniform(0, 2 * np.pi, (m * PD_K, 1, 3))
        x = render(ln, np.ones((m * PD_K, 1)), ph, fs_hz=FS_HZ, ramp_samples=RAMP, cw_samples=CW)
        x = (x + sigma * rng.standard_normal(x.shape)).reshape(m, PD_K, -1)
        res = dsp.process(x)
        ok = res.present & res.valid & (np.abs(res.range_m - R0_M) < 0.5 * CELL_M)
        hit += int(np.count_nonzero(ok.any(axis=1)))
    return hit / n_pix


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pixels", type=int, default=2000, help="noise-only pixels per K")
    ap.add_argument("--pd-pixels", type=int, default=300, help="pixels per SNR of the Pd table")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    t0 = time.process_time()
    out = [HEADER.format(pixels=a.pixels, pd_pixels=a.pd_pixels), "",
           "| K | q (per ramp cell) | alarms / q, Gamma(K) | alarms / q, exponential | gate cells | "
           "false points / cell / pfa, Gamma(K) | exponential |", "|---|---|---|---|---|---|---|"]
    dsp = scan_dsp(pfa=NOISE_PFA)
    q = dsp.ramp_pfa
    for k in KS:
        al, fp, cells = noise_only(dsp, k, a.pixels, seed=k)
        with exponential_model():
            al0, fp0, _ = noise_only(dsp, k, a.pixels, seed=k)
        row = (f"| {k} | {q:.2e} | {al / (2 * cells) / q:.2f} ({al}) | {al0 / (2 * cells) / q:.3f} ({al0}) | {cells:,} | "
               f"{fp / cells / NOISE_PFA:.2f} ({fp}) | {fp0 / cells / NOISE_PFA:.2f} ({fp0}) |")
        out.append(row)
        print(row, flush=True)
    out += ["", PD_TEXT, "", "| SNR per record (dB) | Pd, Gamma(K) | Pd, exponential |", "|---|---|---|"]
    dsp = scan_dsp()
    for i, snr in enumerate(SNRS_DB):
        p1 = pd(dsp, snr, a.pd_pixels, seed=100 + i)
        with exponential_model():
            p0 = pd(dsp, snr, a.pd_pixels, seed=100 + i)
        row = f"| {snr:.0f} | {p1:.3f} | {p0:.3f} |"
        out.append(row)
        print(row, flush=True)
    load = os.getloadavg()[0]
    out.append("")
    out.append(f"CPU {time.process_time() - t0:.0f} s; load average {load:.1f} at the end (2-core Xeon, shared).")
    text = "\n".join(out) + "\n"
    if a.out is not None:
        a.out.write_text(text)
    else:
        print(text)
    return 0


HEADER = """## OS-CFAR on averaged spectra: the Gamma(K) noise model against the exponential one

Produced by `python benchmarks/cfar_averages.py --pixels {pixels} --pd-pixels {pd_pixels} --out docs/measured/27_cfar_averages.md`
(2-core Xeon, shared). The scan's FrameDsp on the default chirp (three-segment, 40 MS/s, 3200-sample
ramps, 10 m gate, benchmarks/resolution_table.py), K records a pixel averaged incoherently before the
per-ramp OS-CFAR (N = 16, k = 12). "Gamma(K)": alpha and the noise scale from lidard.dsp.detect.os_gamma;
"exponential": the same code with Rohling's factor whatever K (the detector before).

### (a) Noise-only pixels: the rate the detector runs at, {pixels} pixels per K, pfa = 1e-5

Alarms: detections of the per-ramp OS-CFAR per ramp cell of the gate, over its level q (FrameDsp.ramp_pfa,
q = sqrt(pfa / m), m = 10); at K = 1 the Hann window's correlation of neighbouring cells raises it over 1
(lidard/dsp/detect/cfar.py). False points: valid points per gate cell, over pfa. Counts in brackets."""

PD_TEXT = """### (b) Pd against SNR at K = 10, default pfa (1e-11)

One static return at 5 m, a random phase per record; Pd = pixels with a valid point within half a
range cell (8.7 mm) of the truth; SNR = one record's post-FFT SNR of one ramp (rectangular, on-bin)."""


if __name__ == "__main__":
    raise SystemExit(main())
