"""Speed versus error of every sub-bin estimator in lidard.dsp.ranging.estimators (dissertation eq. 2-1:
range error = c * frequency error / (2 gamma)).

What is measured
----------------
* Signal: one real cosine per ramp, A cos(2 pi f n / N + phi), random phase, f = N/4 + offset,
  offsets swept 0 .. 0.5 bin, plus white Gaussian noise.
* Post-FFT SNR (the swept quantity): peak-bin power over the mean noise power of one bin, for an
  on-bin tone with a RECTANGULAR window and no zero-padding: rho = N A^2 / (4 sigma^2).  (With the
  Hann window used for detection the displayed peak is 10 log10(1.5) = 1.76 dB lower.)
* Reference: Rife-Boorstyn CRLB, var = 6 N^2 / ((2 pi)^2 rho (N^2 - 1)) bins^2 (lidard/dsp/ranging/crlb.py).
* Peak picking: argmax of the Hann-windowed power spectrum over bins 3 .. N/2 (so noise can win
  at low SNR).  Outlier: |error| > 0.5 bin.  RMSE and bias are computed over inliers;
  "RMSE/CRLB" is RMSE / sqrt(CRLB) (a standard-deviation ratio; the target is <= 1.1 at >= 20 dB
  for the default estimator at EVERY offset, so the worst offset is reported).
* Timing, on ONE core (BLAS threads pinned to 1 before numpy loads), best of 3 runs over a batch:
  "est"      estimator only, given the Hann spectrum and the peak bins;
  "pipeline" Hann rFFT + argmax peak pick + estimator.
  Reported as microseconds per ramp and ramps per second.

Usage: python benchmarks/speed_vs_error.py [--quick]   (writes benchmarks/out/speed_vs_error.png)
"""

from __future__ import annotations

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import pathlib  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from lidard.dsp.ranging.crlb import crlb_freq_var_post_fft  # noqa: E402
from lidard.dsp.ranging.estimators import DEFAULT_METHOD, ESTIMATOR_NAMES, estimate  # noqa: E402
from lidard.dsp.spectrum.window import get_window  # noqa: E402

SNRS_DB = (10, 20, 30)
OUT = pathlib.Path(__file__).resolve().parent / "out" / "speed_vs_error.png"


def make_ramps(n: int, f_bins: float, snr_db: float, batch: int, rng: np.random.Generator) -> np.ndarray:
    rho = 10 ** (snr_db / 10)
    sigma = np.sqrt(n / (4 * rho))  # A = 1
    t = np.arange(n)
    phi = rng.uniform(0, 2 * np.pi, (batch, 1))
    return np.cos(2 * np.pi * f_bins * t / n + phi) + sigma * rng.standard_normal((batch, n))


def spectrum_and_peaks(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    spec = np.fft.rfft(x * w, axis=-1)
    p = spec.real**2 + spec.imag**2
    return spec, np.argmax(p[:, 3:], axis=-1) + 3


def accuracy(n: int, offsets: np.ndarray, trials: int, seed: int) -> dict:
    """stats[method][snr] = dict(worst_ratio, ratios per offset, max |bias|/sqrt(crlb), outlier rate)."""
    rng = np.random.default_rng(seed)
    w = get_window("hann", n)
    stats: dict = {m: {} for m in ESTIMATOR_NAMES}
    for snr_db in SNRS_DB:
        crlb = float(crlb_freq_var_post_fft(10 ** (snr_db / 10), n))
        per = {m: ([], [], []) for m in ESTIMATOR_NAMES}
        for off in offsets:
            f = n / 4 + off
            x = make_ramps(n, f, snr_db, trials, rng)
            spec, k = spectrum_and_peaks(x, w)
            for m in ESTIMATOR_NAMES:
                err = estimate(x, k, method=m, window="hann", spectrum=spec) - f
                inl = np.abs(err) <= 0.5
                e = err[inl]
                per[m][0].append(np.sqrt(np.mean(e**2) / crlb) if e.size else np.inf)
                per[m][1].append(abs(np.mean(e)) / np.sqrt(crlb) if e.size else np.inf)
                per[m][2].append(1.0 - np.mean(inl))
        for m in ESTIMATOR_NAMES:
            r, b, o = (np.array(v) for v in per[m])
            stats[m][snr_db] = {"ratios": r, "worst_ratio": float(r.max()), "bias": float(b.max()), "outliers": float(o.mean())}
    return stats


def timing(n: int, batch: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    w = get_window("hann", n)
    x = make_ramps(n, n / 4 + 0.3, 20, batch, rng)
    spec, k = spectrum_and_peaks(x, w)
    out = {}
    for m in ESTIMATOR_NAMES:
        estimate(x[:64], k[:64], method=m, window="hann", spectrum=spec[:64])  # warm caches
        est_t, pipe_t = [], []
        for _ in range(3):
            t0 = time.perf_counter()
            estimate(x, k, method=m, window="hann", spectrum=spec)
            t1 = time.perf_counter()
            s2, k2 = spectrum_and_peaks(x, w)
            estimate(x, k2, method=m, window="hann", spectrum=s2)
            t2 = time.perf_counter()
            est_t.append(t1 - t0)
            pipe_t.append(t2 - t1)
        out[m] = (min(est_t) / batch, min(pipe_t) / batch)
    return out


def plot(results: dict, path: pathlib.Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(16, 5))
    markers = {512: "o", 4096: "s"}
    colors = dict(zip(ESTIMATOR_NAMES, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    for n, (stats, times) in results.items():
        for m in ESTIMATOR_NAMES:
            xs = [times[m][0] * 1e6] * len(SNRS_DB)
            ys = [stats[m][s]["worst_ratio"] for s in SNRS_DB]
            axes[0].scatter(xs, ys, marker=markers[n], color=colors[m], label=f"{m} N={n}")
            for s, y in zip(SNRS_DB, ys):
                axes[0].annotate(f"{s}dB", (xs[0], y), fontsize=6)
            axes[1].plot(SNRS_DB, [stats[m][s]["bias"] for s in SNRS_DB], marker=markers[n], color=colors[m])
            axes[2].plot(SNRS_DB, [stats[m][s]["outliers"] for s in SNRS_DB], marker=markers[n], color=colors[m])
    axes[0].set(xscale="log", yscale="log", xlabel="estimator time per ramp (us, 1 core, given the FFT)",
                ylabel="worst-offset RMSE / sqrt(CRLB)", title="speed vs error")
    axes[0].axhline(1.1, color="k", lw=0.8, ls="--")
    axes[0].legend(fontsize=6, ncol=2)
    axes[1].set(yscale="log", xlabel="post-FFT SNR (dB)", ylabel="max |bias| / sqrt(CRLB)", title="bias")
    axes[2].set(xlabel="post-FFT SNR (dB)", ylabel="outlier rate (|err| > 0.5 bin)", title="outliers")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_speed_vs_error(quick: bool = False, png: pathlib.Path | None = OUT, sizes: dict | None = None) -> dict:
    """Accuracy and timing of every estimator at N = 512 and 4096; writes the PNG if ``png``.

    ``sizes`` overrides the trials/batch per N ({512: dict(trials=..., batch=...), 4096: ...}).

    Returns {"results": {n: (stats, times)}, "trials": {n: trials}, "offsets": [...], "default": name,
    "accuracy_met": bool, "speed_met": bool, "ratio_uncertainty": float}.
    """
    cfg = {
        512: dict(trials=600 if quick else 4000, batch=5000 if quick else 20000),
        4096: dict(trials=150 if quick else 2000, batch=800 if quick else 3000),
    } if sizes is None else sizes
    offsets = np.linspace(0, 0.5, 3 if quick else 6)
    results = {}
    for n, c in cfg.items():
        stats = accuracy(n, offsets, c["trials"], seed=n)
        times = timing(n, c["batch"], seed=n + 1)
        results[n] = (stats, times)
    if png is not None:
        plot(results, pathlib.Path(png))
    ok_acc = all(results[n][0][DEFAULT_METHOD][s]["worst_ratio"] <= 1.1 for n in results for s in SNRS_DB if s >= 20)
    ok_speed = 1 / results[512][1][DEFAULT_METHOD][0] >= 100_000
    unc = max(2.0 / np.sqrt(2.0 * c["trials"]) for c in cfg.values())  # ~2 sigma of an RMSE ratio
    return {"results": results, "trials": {n: c["trials"] for n, c in cfg.items()},
            "offsets": offsets.tolist(), "default": DEFAULT_METHOD, "accuracy_met": ok_acc,
            "speed_met": ok_speed, "ratio_uncertainty": float(unc)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer trials and offsets (~15 s)")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    out = run_speed_vs_error(args.quick, OUT)
    results, offsets = out["results"], np.array(out["offsets"])

    print(f"post-FFT SNR = on-bin peak power / noise power per bin (rectangular window); offsets {np.round(offsets, 2).tolist()} bin")
    print("RMSE/CRLB = worst-offset inlier RMSE / sqrt(CRLB); bias = max |bias| / sqrt(CRLB); out = outlier rate")
    print("est = estimator only given the FFT; pipe = Hann rFFT + argmax + estimator; one core\n")
    hdr = f"{'N':>5} {'method':<11} {'est us':>7} {'est ramps/s':>11} {'pipe us':>8} {'pipe ramps/s':>12}"
    for s in SNRS_DB:
        hdr += f" | {s:>2}dB RMSE/CRLB bias   out"
    print(hdr)
    for n, (stats, times) in results.items():
        for m in ESTIMATOR_NAMES:
            te, tp = times[m]
            line = f"{n:>5} {m + ('*' if m == DEFAULT_METHOD else ''):<11} {te * 1e6:7.2f} {1 / te:11.0f} {tp * 1e6:8.2f} {1 / tp:12.0f}"
            for s in SNRS_DB:
                st = stats[m][s]
                line += f" |      {st['worst_ratio']:8.3f} {st['bias']:5.2f} {st['outliers']:5.3f}"
            print(line)
    print(f"\n* default estimator ({DEFAULT_METHOD}); per-offset RMSE/CRLB of the default:")
    for n, (stats, _) in results.items():
        for s in SNRS_DB:
            print(f"  N={n:<5} {s:>2} dB: " + " ".join(f"{r:.3f}" for r in stats[DEFAULT_METHOD][s]["ratios"]))
    d512 = results[512]
    ok_acc, ok_speed, unc = out["accuracy_met"], out["speed_met"], out["ratio_uncertainty"]
    print(f"\ntarget RMSE <= 1.1 sqrt(CRLB) at >= 20 dB, every offset: {'MET' if ok_acc else 'NOT MET'}"
          f" (each ratio carries about +-{unc:.3f} statistical error at 2 sigma{'; --quick is not conclusive' if args.quick else ''})")
    print(f"target >= 100k ramps/s at N=512 (estimator only): {'MET' if ok_speed else 'NOT MET'} "
          f"({1 / d512[1][DEFAULT_METHOD][0]:.0f}/s; pipeline {1 / d512[1][DEFAULT_METHOD][1]:.0f}/s)")
    print(f"wrote {OUT}  ({time.perf_counter() - t_start:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
