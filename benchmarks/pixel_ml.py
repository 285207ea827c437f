"""Benchmark: one refinement per pixel (the likelihood summed over its records) against the mean of
per-record refinements, on the frame DSP's front end (lidard.dsp.frame.FrameDsp, real receiver).

Pixels are drawn in this script (no bench): L = 10 records of an up and a down ramp, each record
with its own random phase per return, in white noise, on the scan's chirp (8.6 GHz in 80 us,
records 238 us apart: 2 x 80 us of ramps and the three-segment chirp's 78 us hold), the ramps
windowed to their central 90 %. Two geometries: the lab scene's 0.4 m/s band (5 MS/s, 400-sample
ramps) and the 10 m/s band (40 MS/s, 3200-sample ramps). SNR: one ramp's post-FFT SNR of one record
(rectangular window, on-bin: N A^2 / (4 sigma^2), lidard.dsp.ranging.crlb). Each return sits at a random
sub-bin offset. What is measured is the front end's beat frequency of each ramp (``_plain_front_end``:
detection, refinement, the model-order test), not the pairing.

Tables (the same seeded pixels through two trees, each on PYTHONPATH in a child process):

* one static return, SNR sweep from the detector's threshold up: the fraction of ramps detected,
  the frequency error's bias and std (bins of the ramp's grid; 1 bin = 19.4 mm of range from one
  ramp) over the detected ones, the Cramer-Rao bound for L records (crlb_tones_freq_var), var / CRLB,
  and the ramps more than 5 CRLB std off (outliers);
* two equal returns 1-3 bins apart: both detected and resolved, each tone's std against the
  two-tone bound (averaged over the trials' phases);
* moving targets: a return at 1.3 m receding at v: range from the two ramps (the regime known),
  its bias and std against the range at the pixel's measurement time
  (FrameDsp.measurement_delay_s), and the ramps flagged unresolved by the model-order test.

Run: python benchmarks/pixel_ml.py --old /path/to/main [--trials 300] [--out docs/measured/27_pixel_ml.md]
(``--worker``: this tree only, JSON on stdout.)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

C = 299_792_458.0
KAPPA = 8.6e9 / 80e-6           # chirp rate (Hz/s)
WAVELENGTH = 1.55e-6
PERIOD_S = 238e-6               # one record: up, down and the hold
L = 10
BANDS = {0.4: (5e6, 400), 10.0: (40e6, 3200)}    # band (m/s) -> (fs, ramp samples)
SNRS_DB = (12.0, 14.0, 15.0, 16.0, 18.0, 20.0, 30.0)
SEPARATIONS = (1.0, 1.5, 2.0, 3.0)
SPEEDS = {0.4: (0.0, 0.2, 0.4), 10.0: (0.0, 1.0, 2.0, 5.0, 10.0)}


def _dsp(band: float):
    from lidard.dsp.frame import FrameDsp
    fs, ramp = BANDS[band]
    # the three-segment record (its hold after the ramps: the records' period); its CW spectrum is not read here
    return FrameDsp(ramp_samples=ramp, fs_hz=fs, chirp_rate_hz_per_s=KAPPA, wavelength_m=WAVELENGTH,
                    max_range_m=2.0, max_speed_mps=band, cw_samples=round(PERIOD_S * fs) - 2 * ramp)


def _records(rng, dsp, returns, sigma):
    """(P, L, 2 ramp) records; ``returns``: list of (amp (P,), range (P,), speed) per return."""
    fs, n = dsp.fs_hz, dsp.ramp_samples
    p_n = returns[0][0].shape[0]
    t = np.arange(n) / fs
    x = rng.normal(0.0, sigma, (p_n, L, 2 * n))
    for amp, r0, v in returns:
        f_d = -2.0 * v / WAVELENGTH
        for ramp, sign in ((0, -1.0), (1, 1.0)):
            t0 = np.arange(L)[:, None] * PERIOD_S + ramp * n / fs           # (L, 1) start of each ramp
            # beat phase: 2 pi (f_R(t) -+ f_D) integrated over the ramp, f_R = 2 kappa R(t) / c
            f0 = 2 * KAPPA * (r0[:, None, None] + v * t0[None]) / C + sign * f_d           # (P, L, 1)
            ph = 2 * np.pi * (f0 * t + 0.5 * (2 * KAPPA * v / C) * t * t) + rng.uniform(0, 2 * np.pi, (p_n, L, 1))
            x[..., ramp * n:(ramp + 1) * n] += amp[:, None, None] * np.cos(ph)
    return x


def _sigma_for(snr_db: float, n_used: int, amp: float = 1.0) -> float:
    return float(np.sqrt(n_used * amp ** 2 / (4 * 10 ** (snr_db / 10))))


def _bins(dsp, r, v, ramp):
    """The beat of ``ramp`` (0 up, 1 down) at the pixel's measurement time, bins of the ramp grid."""
    f_r = 2 * KAPPA * r / C
    f_d = -2 * v / WAVELENGTH
    return np.abs(f_r + (1 if ramp else -1) * f_d) / dsp.rfft.delta_f


def one_tone(rng, trials: int) -> list[dict]:
    from lidard.dsp.ranging.crlb import crlb_tones_freq_var
    dsp = _dsp(0.4)
    n = dsp.n_used
    out = []
    for snr in SNRS_DB:
        sigma = _sigma_for(snr, n)
        r = rng.uniform(0.8, 1.6, trials)
        x = _records(rng, dsp, [(np.ones(trials), r, 0.0)], sigma)
        f, det = dsp._plain_front_end(x, 1.0)
        truth = _bins(dsp, r, 0.0, 0)
        got = f[0] / dsp.rfft.delta_f
        hit = det[0].valid & (np.abs(got - truth[:, None]) < 2.0)
        seen = hit.any(axis=1)
        err = np.where(hit, got - truth[:, None], 0.0).sum(axis=1)[seen]
        # the bound of one record's tone in this window, L records (their phases do not matter here)
        bound = float(np.ravel(crlb_tones_freq_var([n / 4 + 0.3], np.ones((L, 1)), rng.uniform(0, 6, (L, 1)), n,
                                                   sigma))[0])
        out.append(dict(snr_db=snr, detected=float(seen.mean()), bias=float(err.mean()) if err.size else None,
                        std=float(err.std()) if err.size else None, crlb_std=bound ** 0.5,
                        outliers=float(np.mean(np.abs(err) > 5 * bound ** 0.5)) if err.size else None))
    return out


def two_tones(rng, trials: int) -> list[dict]:
    from lidard.dsp.ranging.crlb import crlb_tones_freq_var
    dsp = _dsp(0.4)
    n, bin_m = dsp.n_used, dsp.range_resolution_m
    out = []
    for snr in (20.0, 30.0):
        sigma = _sigma_for(snr, n)
        for sep in SEPARATIONS:
            r = rng.uniform(0.8, 1.4, trials)
            x = _records(rng, dsp, [(np.ones(trials), r, 0.0), (np.ones(trials), r + sep * bin_m, 0.0)], sigma)
            f, det = dsp._plain_front_end(x, 1.0)
            got = f[0] / dsp.rfft.delta_f
            ok = det[0].valid & ~det[0].unresolved
            truth = np.stack([_bins(dsp, r, 0.0, 0), _bins(dsp, r + sep * bin_m, 0.0, 0)], axis=1)
            both = ok.sum(axis=1) >= 2
            est = np.sort(np.where(ok, got, np.inf), axis=1)[:, :2]
            err = (est - truth)[both]
            good = np.all(np.abs(err) < 0.5, axis=1)
            err = err[good]
            bounds = [np.mean([crlb_tones_freq_var([50.3, 50.3 + sep], np.ones((L, 2)), rng.uniform(0, 6, (L, 2)),
                                                   n, sigma) for _ in range(8)], axis=0)]
            out.append(dict(snr_db=snr, sep=sep, resolved=float(np.mean(both)), within=float(good.sum() / trials),
                            std=[float(s) for s in err.std(axis=0)] if err.size else None,
                            bias=[float(s) for s in err.mean(axis=0)] if err.size else None,
                            crlb_std=[float(s) for s in np.sqrt(bounds[0])]))
    return out


def moving(rng, trials: int) -> list[dict]:
    out = []
    for band, speeds in SPEEDS.items():
        dsp = _dsp(band)
        sigma = _sigma_for(25.0, dsp.n_used)
        for v in speeds:
            r = rng.uniform(1.2, 1.4, trials)
            x = _records(rng, dsp, [(np.ones(trials), r, v)], sigma)
            f, det = dsp._plain_front_end(x, 1.0)
            rm = r + v * (dsp.ramp_samples / dsp.fs_hz + 0.5 * (L - 1) * PERIOD_S)   # the pixel's middle
            up_t, dn_t = _bins(dsp, rm, v, 0), _bins(dsp, rm, v, 1)
            ups, dns = (f[i] / dsp.rfft.delta_f for i in (0, 1))
            pick = []
            for got, truth, d in ((ups, up_t, det[0]), (dns, dn_t, det[1])):
                near = d.valid & (np.abs(got - truth[:, None]) < 3.0)
                j = np.argmax(near, axis=1)
                rows = np.arange(trials)
                pick.append((near.any(axis=1), got[rows, j], d.unresolved[rows, j] & near.any(axis=1)))
            (su, fu, uu), (sd, fd, ud) = pick
            seen = su & sd
            folded = 2 * KAPPA * rm / C < 2 * abs(v) / WAVELENGTH
            f_r = np.where(folded, np.abs(fd - fu) / 2, (fu + fd) / 2) * dsp.rfft.delta_f
            err = (C * f_r / (2 * KAPPA) - rm)[seen] * 1e3
            out.append(dict(band=band, v=v, detected=float(seen.mean()), bias_mm=float(err.mean()),
                            std_mm=float(err.std()), unresolved=float(np.mean((uu | ud)[seen])),
                            drift_bins=float(2 * KAPPA * v * PERIOD_S * (L - 1) / C / dsp.rfft.delta_f)))
    return out


def below_threshold(rng, trials: int) -> list[dict] | None:
    """The estimators alone from the averaged spectrum's peak cell (no detector): the pixel fit against
    the mean of per-record ``newton`` refinements, N = 360, L = 10, SNR under the frame detector's
    threshold. None in a tree without the pixel fit."""
    try:
        from lidard.dsp.ranging.pixeltone import refine_pixel_tone
    except ImportError:
        return None
    from lidard.dsp.ranging.crlb import crlb_tones_freq_var
    from lidard.dsp.ranging.estimators import estimate, pooled_jacobsen
    from lidard.dsp.spectrum.rangefft import RangeFFT
    n = 360
    rf = RangeFFT(n, 1.0, 1.0, window="hann")
    t = np.arange(n)
    out = []
    for snr in (6.0, 9.0, 12.0, 16.0):
        sigma = _sigma_for(snr, n)
        f = rng.uniform(60.0, 61.0, 4 * trials)
        x = np.cos(2 * np.pi * f[:, None, None] * t / n + rng.uniform(0, 2 * np.pi, (f.size, L, 1)))
        x = x + sigma * rng.standard_normal(x.shape)
        spec = rf(x)
        k = 55 + np.argmax((spec.real ** 2 + spec.imag ** 2).mean(axis=1)[:, 55:67], axis=1)
        new = refine_pixel_tone(x, pooled_jacobsen(spec, k[:, None], window="hann", n_samples=n)[:, 0])[0]
        old = estimate(x, np.broadcast_to(k[:, None], x.shape[:2]), method="newton", window="hann",
                       spectrum=spec).mean(axis=1)
        b = float(np.ravel(crlb_tones_freq_var([60.3], np.ones((L, 1)), rng.uniform(0, 6, (L, 1)), n, sigma))[0])
        row = dict(snr_db=snr, crlb_std=b ** 0.5, pixels=int(f.size))
        for tag, est in (("old", old), ("new", new)):
            e = est - f
            row[tag] = dict(std=float(e.std()), ratio=float(e.var() / b), outliers=float(np.mean(np.abs(e) > 5 * b ** 0.5)))
        out.append(row)
    return out


def worker(trials: int, seed: int) -> dict:
    from lidard.dsp.spectrum import jit
    jit.kernels()
    t0 = time.process_time()
    res = {}
    for name, fn in (("one_tone", one_tone), ("two_tones", two_tones), ("moving", moving)):
        res[name] = fn(np.random.default_rng(seed), trials)
    res["cpu_s"] = time.process_time() - t0
    res["below_threshold"] = below_threshold(np.random.default_rng(seed + 1), trials)
    return res


def _f(v, fmt=".4f") -> str:
    return "-" if v is None else format(v, fmt)


def tables(old: dict, new: dict) -> str:
    lines = ["### One static return, L = 10 records (0.4 m/s band: N = 360 used samples a ramp)", "",
             "| SNR one record (dB) | detected old / new | bias old / new (bin) | std old / new (bin) | CRLB std (bin) "
             "| var/CRLB old / new | outliers > 5 sd old / new |", "|---|---|---|---|---|---|---|"]
    for a, b in zip(old["one_tone"], new["one_tone"]):
        c = a["crlb_std"]
        ratio = [None if s["std"] is None else (s["std"] / c) ** 2 for s in (a, b)]
        lines.append(f"| {a['snr_db']:.0f} | {a['detected']:.3f} / {b['detected']:.3f} | {_f(a['bias'])} / {_f(b['bias'])} "
                     f"| {_f(a['std'])} / {_f(b['std'])} | {c:.4f} | {_f(ratio[0], '.2f')} / {_f(ratio[1], '.2f')} "
                     f"| {_f(a['outliers'], '.3f')} / {_f(b['outliers'], '.3f')} |")
    if new.get("below_threshold"):
        lines += ["", "### The estimators alone under the detector's threshold (N = 360, L = 10; no detector: the "
                  "averaged spectrum's peak cell near the tone)", "",
                  "| SNR one record (dB) | pixels | CRLB std (bin) | mean of record fits: std, var/CRLB, outliers "
                  "| pixel fit: std, var/CRLB, outliers |", "|---|---|---|---|---|"]
        for r in new["below_threshold"]:
            o, w = r["old"], r["new"]
            lines.append(f"| {r['snr_db']:.0f} | {r['pixels']} | {r['crlb_std']:.4f} | {o['std']:.4f}, {o['ratio']:.2f}, "
                         f"{o['outliers']:.4f} | {w['std']:.4f}, {w['ratio']:.2f}, {w['outliers']:.4f} |")
    lines += ["", "### Two equal static returns, L = 10 (0.4 m/s band)", "",
              "| SNR (dB) | apart (bins) | both resolved old / new | both within 0.5 bin old / new "
              "| std near, far old (bin) | std near, far new (bin) | two-tone CRLB std (bin) |",
              "|---|---|---|---|---|---|---|"]
    for a, b in zip(old["two_tones"], new["two_tones"]):
        def pair(v):
            return "-" if v is None else f"{v[0]:.4f}, {v[1]:.4f}"
        lines.append(f"| {a['snr_db']:.0f} | {a['sep']:.1f} | {a['resolved']:.3f} / {b['resolved']:.3f} "
                     f"| {a['within']:.3f} / {b['within']:.3f} | {pair(a['std'])} | {pair(b['std'])} | {pair(a['crlb_std'])} |")
    lines += ["", "### Moving target, 1.3 m, SNR 25 dB a record, L = 10", "",
              "| band (m/s) | v (m/s) | beat drift over the pixel (bins) | detected old / new | range bias old / new (mm) "
              "| range std old / new (mm) | flagged unresolved old / new |", "|---|---|---|---|---|---|---|"]
    for a, b in zip(old["moving"], new["moving"]):
        lines.append(f"| {a['band']:g} | {a['v']:g} | {a['drift_bins']:.3f} | {a['detected']:.3f} / {b['detected']:.3f} "
                     f"| {a['bias_mm']:+.3f} / {b['bias_mm']:+.3f} | {a['std_mm']:.3f} / {b['std_mm']:.3f} "
                     f"| {a['unresolved']:.3f} / {b['unresolved']:.3f} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", help="the other tree (its lidard on PYTHONPATH in a child)")
    ap.add_argument("--trials", type=int, default=300)
    ap.add_argument("--seed", type=int, default=27)
    ap.add_argument("--worker", action="store_true")
    ap.add_argument("--out")
    a = ap.parse_args()
    if a.worker:
        print(json.dumps(worker(a.trials, a.seed)))
        return 0
    if not a.old:
        ap.error("--old is needed (or --worker)")
    here = str(Path(__file__).resolve().parents[1])
    res = {}
    for tag, tree in (("old", a.old), ("new", here)):
        env = {**os.environ, "PYTHONPATH": tree, "OPENBLAS_NUM_THREADS": "1"}
        got = subprocess.run([sys.executable, __file__, "--worker", "--trials", str(a.trials), "--seed", str(a.seed)],
                             env=env, capture_output=True, text=True, check=True)
        res[tag] = json.loads(got.stdout.strip().splitlines()[-1])
    text = ("## One refinement per pixel: the likelihood summed over its records against the mean of record fits\n\n"
            f"Command: `python benchmarks/pixel_ml.py --old <main tree> --trials {a.trials} --seed {a.seed}` "
            "(old: the tree given, new: this one; the same seeded pixels through both).\n\n")
    text += tables(res["old"], res["new"])
    text += (f"\n(CPU of the whole worker, synthesis included: old {res['old']['cpu_s']:.1f} s, new "
             f"{res['new']['cpu_s']:.1f} s; load average {os.getloadavg()[0]:.1f})\n")
    print(text)
    if a.out:
        Path(a.out).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
