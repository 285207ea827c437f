"""Benchmark: two returns a few range cells apart, through the frame DSP (its joint model, lidard.dsp.ranging).

Pixels are drawn from the tone model of lidard.dsp.ranging.lines (no daemon, no bench): two returns,
the near one at 5 m and the far one 0.5-6 range cells (c / 2B = 17.4 mm) behind it, each with a
random phase per segment, in white noise, on the scan's default chirp (the three-segment chirp of
config/sim.toml at a 10 m gate: 40 MS/s, 3200-sample ramps, one record per pixel) and the scan's
FrameDsp. SNR: the stronger return's post-FFT SNR of one ramp (rectangular window, on-bin: N A^2 /
(4 sigma^2), lidard.dsp.ranging.crlb); "unequal": the near return 10 dB under the far one (a pane in front
of a wall); "moving": the far return recedes at 1 m/s. Per cell: the fraction of pixels with BOTH
returns valid (each within half a cell of its truth), the range RMSE and bias of those points, and
the two-tone Cramer-Rao bound on the range (lidard.dsp.ranging.crlb.crlb_tones_freq_var on each ramp, the
range being the mean of the two ramps' beats).

Then the noise-only check: pixels of white noise, every gate cell of every pixel a place where a
false point could appear; the false points per gate cell against the pfa the DSP was given.

Run: python benchmarks/resolution_table.py [--pixels 200] [--out docs/measured/25_joint_model.md]
"""

from __future__ import annotations

import argparse
import os

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too

import numpy as np

from lidard.dsp.ranging.crlb import crlb_tones_freq_var
from lidard.dsp.frame import FrameDsp
from lidard.dsp.ranging.lines import lines, render
from lidard.dsp.spectrum.rangefft import C_M_PER_S

FS_HZ, RAMP, CW = 40e6, 3200, 3120
#: the two false-point rates checked on noise-only pixels
PFAS = (1e-6, 3e-6)
RATE = 8.6e9 / 80e-6
WAVELENGTH = 1.55e-6
CELL_M = C_M_PER_S / (2 * 8.6e9)
R0_M = 5.0
SEPS = (0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0)
SNRS = (20.0, 30.0, 40.0)


HEADER = """## Two returns a few range cells apart: the joint model (lidard/dsp/ranging)

Produced by `python benchmarks/resolution_table.py --out docs/measured/25_joint_model.md` (2-core Xeon,
shared; load average {load:.1f} at the end; {cpu:.0f} s of CPU). Pixels drawn from the tone model
(lidard.dsp.ranging.lines) on the scan's default chirp (three-segment, 40 MS/s, 3200-sample ramps,
one record per pixel) through the scan's FrameDsp: two returns, the near one at 5 m, the far one
0.5-6 cells (c / 2B = 17.4 mm) behind; SNR = the stronger return's post-FFT SNR of one ramp
(rectangular, on-bin); "near -10 dB": the near return 10 dB under the far one; "far 1 m/s": the far
return recedes at 1 m/s. Both valid = each return has a valid point within half a cell of its truth.
RMSE and bias over those points; the two-tone CRLB from lidard.dsp.ranging.crlb.crlb_tones_freq_var (both
ramps); RMSE / CRLB the larger of the two returns'. 200 pixels per row."""

FP_TEXT = """### Noise-only pixels: the false-point rate that `scan.pfa` states

White noise through the same FrameDsp at two pfa settings; a gate cell is a bin of the searched band
(FrameDsp.bin_range, c / 2B). `scan.pfa` is the rate of valid false points per range cell: a point is a
(range, velocity) hypothesis whose lines both ramps detect, in noise q^2 per hypothesis at a per-ramp
level q, and a range cell holds m hypotheses noise can complete (the three-segment chirp: the static
ones, whose |f_D| lies in the CW spectrum's DC guard; lidard/dsp/ranging/points.py), so the per-ramp
OS-CFAR runs at q = sqrt(pfa / m) (m = 10 here), keeping max_returns candidate peaks per ramp plus
the median count of noise alarms q lets through the band (FrameDsp.candidate_slots; none at these two
settings nor at the default 1e-11; the points are cut back to max_returns). Enough pixels for ~25 expected false points and
>= 1e6 cells. The detector's alarms per ramp cell exceed its level (a Hann window correlates
neighbouring cells, lidard/dsp/detect/cfar.py); the pairing's own tests (CW evidence, the pair's power
balance) take about as many back."""

SCENES_TEXT = """### The issue's scenes on the simulated bench

Nominal bench (tolerances off), linearized, 16 x 16 ROI at 1 m (192 pixels), 2 m gate: a glass pane
(albedo 0.5, transmission 0.5; 0.125 for the faint one, 12 dB under) in front of a retro-reflective
sheet (albedo 2.0). Before the joint model (issue 25's report): 0 of 192 pixels with both surfaces valid
at 2, 3 and 4 cells, with the faint pane and at 6 cm; both ranges biased ~+2 mm."""


def scan_dsp(**over) -> FrameDsp:
    """The scan's FrameDsp for config/sim.toml at a 10 m gate (lidard.instrument.scan_loop.plan_scan)."""
    kw = dict(ramp_samples=RAMP, fs_hz=FS_HZ, chirp_rate_hz_per_s=RATE, wavelength_m=WAVELENGTH, max_range_m=10.0,
              max_speed_mps=10.0, window="hann", pfa=1e-11, max_returns=2, cw_samples=CW)
    kw.update(over)
    return FrameDsp(**kw)


def draw(dsp: FrameDsp, rng, n_pix: int, sep_cells: float, snr_db: float, unequal: bool, moving: bool):
    """(records (n_pix, 1, 2 RAMP + CW), true ranges (2,), amplitudes (2,), sigma, phases (n_pix, 2, 3))."""
    r = np.array([R0_M, R0_M + sep_cells * CELL_M])
    v = np.array([0.0, 1.0 if moving else 0.0])
    amp = np.array([10 ** (-10 / 20) if unequal else 1.0, 1.0])
    sigma = np.sqrt(dsp.n_used / (4 * 10 ** (snr_db / 10)))
    ln = lines(r, v, chirp_rate_hz_per_s=RATE, wavelength_m=WAVELENGTH)
    ph = rng.uniform(0, 2 * np.pi, (n_pix, 2, 3))
    x = render(ln, np.broadcast_to(amp, (n_pix, 2)), ph, fs_hz=FS_HZ, ramp_samples=RAMP, cw_samples=CW)
    x = x + sigma * rng.standard_normal(x.shape)
    return x[:, None, :], r, amp, sigma, ph, ln


def crlb_range_m(dsp, ln, amp, sigma, ph) -> np.ndarray:
    """Two-tone bound on each return's range (2,), mean of the variance over the pixels' phases (a few)."""
    df = dsp.fs_hz / dsp.n_used
    var = np.zeros(2)
    sub = ph[:8]
    for p in sub:
        for seg, f in ((0, ln.up_hz), (1, ln.down_hz)):
            var += crlb_tones_freq_var(np.abs(f) / df, amp[None], p[None, :, seg], dsp.n_used, sigma)
    var /= len(sub)
    # range = c (f_up + f_dn) / (4 kappa): var = (var_up + var_dn) / 4 in Hz^2 (summed above over both)
    return C_M_PER_S / (2 * RATE) * np.sqrt(var / 4) * df


def score(res, r_true) -> tuple[np.ndarray, np.ndarray]:
    """(both valid per pixel, errors (n_pix, 2) with NaN where that return has no valid point)."""
    rng_m = np.where(res.valid & res.present, res.range_m, np.nan)           # (n_pix, K)
    err = rng_m[:, None, :] - r_true[None, :, None]                           # (n_pix, 2 truths, K)
    near = np.abs(err) < 0.5 * CELL_M
    e = np.where(near, err, np.nan)
    best = np.nanmin(np.where(np.isfinite(e), np.abs(e), np.inf), axis=-1)
    idx = np.argmin(np.where(np.isfinite(e), np.abs(e), np.inf), axis=-1)
    got = np.take_along_axis(e, idx[..., None], axis=-1)[..., 0]
    got = np.where(np.isfinite(best), got, np.nan)
    both = np.isfinite(got).all(axis=1) & (idx[:, 0] != idx[:, 1])
    return both, got


def table(n_pix: int, seed: int) -> list[str]:
    dsp = scan_dsp()
    rng = np.random.default_rng(seed)
    rows = ["| motion | amplitudes | SNR (dB) | cells apart | both valid | RMSE near / far (mm) | bias near / far (mm) "
            "| two-tone CRLB near / far (mm) | RMSE / CRLB |",
            "|---|---|---:|---:|---:|---|---|---|---:|"]
    for moving in (False, True):
        for unequal in (False, True):
            for snr in SNRS:
                for sep in SEPS:
                    x, r, amp, sigma, ph, ln = draw(dsp, rng, n_pix, sep, snr, unequal, moving)
                    res = dsp.process(x)
                    both, got = score(res, r)
                    g = got[both]
                    crlb = crlb_range_m(dsp, ln, amp, sigma, ph) * 1e3
                    if g.shape[0] >= 5:
                        rmse = np.sqrt(np.mean(g ** 2, axis=0)) * 1e3
                        bias = g.mean(axis=0) * 1e3
                        ratio = np.max(rmse / crlb)
                        txt = (f"{rmse[0]:.3f} / {rmse[1]:.3f} | {bias[0]:+.3f} / {bias[1]:+.3f} | "
                               f"{crlb[0]:.3f} / {crlb[1]:.3f} | {ratio:.2f}")
                    else:
                        txt = f"- | - | {crlb[0]:.3f} / {crlb[1]:.3f} | -"
                    line = (f"| {'far 1 m/s' if moving else 'static'} | {'near -10 dB' if unequal else 'equal'} | "
                            f"{snr:.0f} | {sep:g} | {both.mean():.1%} | {txt} |")
                    rows.append(line)
                    print(line, flush=True)
    return rows


def false_points(pfa: float, n_pix: int, seed: int) -> str:
    """Noise-only pixels through the scan's DSP at ``pfa`` (false points per range cell): valid false
    points per gate cell (a bin of the searched band, FrameDsp.bin_range) against pfa, with the per-ramp
    detector's level and its measured alarms per ramp cell."""
    dsp = scan_dsp(pfa=pfa)
    rng = np.random.default_rng(seed)
    lo, hi = dsp.bin_range
    cells = hi - lo + 1
    n_points = n_valid = n_alarms = 0
    done = 0
    while done < n_pix:
        m = min(2000, n_pix - done)
        x = rng.standard_normal((m, 1, 2 * RAMP + CW))
        res = dsp.process(x)
        _, dets = dsp._plain_front_end(x, 1.0)
        n_alarms += sum(int(np.count_nonzero(d.valid)) for d in dets)
        n_points += int(np.count_nonzero(res.present))
        n_valid += int(np.count_nonzero(res.present & res.valid))
        done += m
    total = cells * n_pix
    rate = n_valid / total
    lo_ci, hi_ci = _poisson_ci(n_valid)
    return (f"| {pfa:.0e} | {dsp.ramp_pfa:.2e} | {n_alarms / (2 * total) / dsp.ramp_pfa:.2f} | {n_pix:,} | {total:,} | "
            f"{n_points:,} | {n_valid:,} | {rate:.2e} ({lo_ci / total:.1e}-{hi_ci / total:.1e}) | {rate / pfa:.2f} "
            f"({lo_ci / total / pfa:.2f}-{hi_ci / total / pfa:.2f}) |")


def _poisson_ci(k: int) -> tuple[float, float]:
    """95 % interval of a Poisson count (Garwood)."""
    from scipy.stats import chi2
    lo = 0.0 if k == 0 else chi2.ppf(0.025, 2 * k) / 2
    return lo, chi2.ppf(0.975, 2 * k + 2) / 2


def bench_scenes() -> list[str]:
    """The issue's scenes on the simulated bench (nominal, linearized; 16 x 16 ROI, 192 pixels at 1 m):
    a pane (albedo 0.5, half the light through) 2-6 cells in front of a retro-reflective sheet, a faint
    pane (albedo 0.125, 12 dB under) 4 cells in front, and a pane 6 cm in front."""
    import os
    import threading

    os.environ.setdefault("LIDARD__SIM__TOLERANCES__ENABLED", "false")
    from lidard.config import load_config
    from lidard.instrument import ScanRequest, open_instrument

    inst = open_instrument(load_config("config/sim.toml"), scene_path="config/scenes/empty.toml", bench="embedded")
    rows = ["| scene | pixels | points | valid | pixels with both valid | near RMS / bias (mm) | far RMS / bias (mm) |",
            "|---|---:|---:|---:|---:|---|---|"]
    try:
        cal = inst.linearize()
        bench = inst._on_close.__self__
        for dz, refl in ((2 * CELL_M, 0.5), (3 * CELL_M, 0.5), (4 * CELL_M, 0.5), (6 * CELL_M, 0.5),
                         (4 * CELL_M, 0.125), (0.06, 0.5)):
            inst.set_scene({"target": [
                {"kind": "plane", "point": [0, 0, 1.0], "normal": [0, 0, -1], "reflectivity": refl, "transmission": 0.5},
                {"kind": "plane", "point": [0, 0, 1.0 + dz], "normal": [0, 0, -1], "reflectivity": 2.0}]})
            res = inst.run_scan(ScanRequest(pattern="roi", rows=(56, 72), cols=(56, 72), max_range_m=2.0),
                                lambda p: None, threading.Event(), cal)
            allp = res.points
            pts = allp[allp["valid"] == 1]
            near = bench.ground_truth(pts["row"], pts["col"])
            far = near * (1.0 + dz)
            on_n = np.abs(pts["range"] - near) < 0.5 * CELL_M
            on_f = np.abs(pts["range"] - far) < 0.5 * CELL_M
            pix = pts["row"].astype(np.int64) * 4096 + pts["col"]
            both = np.intersect1d(pix[on_n], pix[on_f]).size
            e_n, e_f = (pts["range"] - near)[on_n] * 1e3, (pts["range"] - far)[on_f] * 1e3
            line = (f"| pane albedo {refl} {dz * 1e3:.1f} mm ({dz / CELL_M:.1f} cells) in front | {res.pixels_scanned} | "
                    f"{len(allp)} | {len(pts)} | {both} | {np.sqrt(np.mean(e_n ** 2)):.3f} / {e_n.mean():+.3f} | "
                    f"{np.sqrt(np.mean(e_f ** 2)):.3f} / {e_f.mean():+.3f} |")
            rows.append(line)
            print(line, flush=True)
    finally:
        inst.close()
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pixels", type=int, default=200, help="pixels per cell of the resolution table")
    ap.add_argument("--noise-count", type=float, default=25.0,
                    help="noise-only pixels per pfa setting: enough for this many expected false points (and >= 1e6 cells)")
    ap.add_argument("--seed", type=int, default=25)
    ap.add_argument("--out", default=None, help="write the tables (markdown) here")
    ap.add_argument("--no-bench", action="store_true", help="skip the scenes on the simulated bench")
    args = ap.parse_args()
    t0 = cpu_time()
    rows = table(args.pixels, args.seed)
    fp = ["| pfa (false points per range cell) | per-ramp level | detector alarms per ramp cell / level | pixels "
          "| gate cells | points | valid points | valid per gate cell (95 % CI) | / pfa (95 % CI) |",
          "|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for pfa in PFAS:
        cells = np.subtract(*scan_dsp().bin_range[::-1]) + 1
        n_pix = int(np.ceil(max(args.noise_count / (pfa * cells), 1e6 / cells)))
        fp.append(false_points(pfa, n_pix, args.seed + 1))
        print(fp[-1], flush=True)
    scenes = [] if args.no_bench else bench_scenes()
    print(f"CPU {cpu_time() - t0:.0f} s")
    if args.out:
        with open(args.out, "w") as fh:
            fh.write("\n".join([HEADER.format(load=os.getloadavg()[0], cpu=cpu_time() - t0), ""] + rows
                               + ["", FP_TEXT, ""] + fp + ["", SCENES_TEXT, ""] + scenes) + "\n")


if __name__ == "__main__":
    main()
