"""Detection probability of the child-bench e2e scan (tests/e2e/test_e2e_scan.py, the plain triangle).

``python benchmarks/child_scan_pd.py --averages 1 2 4 8 --trials 100000`` builds the Pd model of
``test_child_process_bench_over_pty_modbus_and_usb_socket``'s 16 pixels from the bench itself:

1. the signal: the same scan on a ``lidar-sim`` child with white noise and the converter's
   quantization noise off (``sim.effects``), recorded raw: each pixel's noiseless records;
2. the noise: sigma of the records' white noise from the bench's link budget (the detector's
   white-noise ASD and the decimated 8-bit core's quantization, times sqrt(fs / 2), plus the
   record's rounding), and, as a check, measured on a scan of 2 averages with the noise on (the
   difference of a pixel's two records: the signal cancels);
3. Monte Carlo: the noiseless records plus white Gaussian noise of that sigma, ``L`` records a pixel,
   through the frame DSP's ramp spectrum and its OS-CFAR at its per-ramp level (the test's
   ``scan.pfa`` 1e-9: 2.6e-6 a ramp cell); a pixel is found when both ramps detect its line (bins
   39 +- 3). It prints, per L, the misses per ramp, P(a pixel is missed) with its 95 % Poisson
   bounds, P(16 of 16), and the down ramp's margin (peak over the CFAR threshold, dB).

``--seeds 0 1 2 ... --averages 1`` runs the test's scan itself at each bench seed instead (the
child's ``LIDARD__SIM__SEED``): its points, the pixels missed and each pixel's down-ramp margin.

The broad, uncalibrated peak fills the OS-CFAR's reference cells with its own skirts, so its margin
over the threshold is small (~2 dB on the down ramp) although the peak is ~29 dB above the white
noise floor: the noise moves the skirts' cells as much as the peak. The figures are CPU-bound and do
not depend on the load; the child's bench runs the current directory's code.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np

ROWS, COLS = (44, 46), (60, 68)      # the test's region: 16 bonded pixels of the CAL letters
ENV = {"LIDARD__CHIRP__SHAPE": "triangle", "LIDARD__SCAN__PFA": "1e-9"}      # the host's (the test's)
CHILD_ENV = {"LIDARD__SIM__TOLERANCES__ENABLED": "false", "LIDARD__SIM__FACTORY_CALIBRATION": "false"}  # pytest's
QUIET = {"LIDARD__SIM__EFFECTS__NOISE": "false", "LIDARD__SIM__EFFECTS__QUANTIZATION": "false"}
LINE_BIN, NEAR_BINS = 39, 3      # the target's line (0.76 m) and how far a detection may lie from it


def capture(out: Path, averages: int, child_env: dict[str, str]) -> tuple[Path, np.ndarray]:
    """The test's scan on a lidar-sim child (its environment: ``child_env``), recorded raw at ``out``;
    answers ``out`` and the scan's points."""
    from lidard.config import load_config
    from lidard.instrument import ScanRequest, open_instrument

    saved = {k: os.environ.get(k) for k in child_env}
    os.environ.update(child_env)
    try:
        cfg = load_config("config/sim.toml", environ=dict(ENV))
        inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="child")
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    try:
        res = inst.run_scan(ScanRequest(pattern="roi", rows=ROWS, cols=COLS, max_range_m=2.0, averages=averages), lambda p: None,
                            threading.Event(), None, raw_path=out)
    finally:
        inst.close()
    return out, res.points


def _margin_db(p: np.ndarray, ramp_pfa: float, records: int) -> np.ndarray:
    """Per row of ramp power spectra: the largest ratio (dB) of a cell near the line to its OS-CFAR
    threshold (alpha times the ordered statistic of its reference cells, as the frame DSP's)."""
    from lidard.dsp.detect.os_cfar import _noise_os
    from lidard.raw.spectrum import _N_GUARD, _N_REF

    noise, alpha = _noise_os(p, _N_REF // 2, _N_GUARD, ramp_pfa, None, exact=True, records=records)
    near = slice(LINE_BIN - NEAR_BINS, LINE_BIN + NEAR_BINS + 1)
    return 10 * np.log10((p[:, near] / (alpha[None, near] * noise[:, near])).max(axis=1))


def down_margins_db(cap) -> np.ndarray:
    """Per pixel of a capture: the down ramp's margin (dB) at its line, as :func:`detections` measures it."""
    from lidard.raw.replay import replay_dsp
    from lidard.raw.spectrum import _ramp_power

    rep = replay_dsp(cap.attrs)
    beat = cap.chunks(0, cap.n_chunks).channel("beat", cap.channels, cap.averages)
    return _margin_db(_ramp_power(rep, beat, None, None, rep.dsp.ramp_samples), rep.dsp.ramp_pfa, cap.averages)


def seed_scans(seeds: list[int], averages: int, as_json: bool) -> None:
    """The test's scan at each bench seed (``LIDARD__SIM__SEED`` of the child): points, the pixels
    missed and the down ramp's margins."""
    from lidard.raw.capture import RawCapture

    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            path, pts = capture(Path(tmp) / "scan.zarr", averages, {**CHILD_ENV, "LIDARD__SIM__SEED": str(seed)})
            m = down_margins_db(RawCapture(path))
        got = {(int(r), int(c)) for r, c in zip(pts["row"], pts["col"])}
        missed = [(r, c) for r in range(*ROWS) for c in range(*COLS) if (r, c) not in got]
        row = {"seed": seed, "averages": averages, "points": len(pts), "missed": missed,
               "down_margin_db": [round(float(x), 3) for x in m]}
        print(json.dumps(row) if as_json else
              f"seed {seed}: {len(pts)} points, missed {missed}; down margin mean {m.mean():.2f} dB, min {m.min():.2f}")
        sys.stdout.flush()


def budget_sigma_v(fs_hz: float, lsb_v: float) -> float:
    """The records' white-noise sigma from the bench's link budget (module doc, 2)."""
    from lidard.config import load_config
    from lidard.physics.budget import quantization_asd
    from sim_devices.bench.bench import Bench

    cfg = load_config("config/sim.toml", environ={**ENV, **CHILD_ENV})
    bench = Bench(cfg)
    try:
        a = cfg.adc
        asd = math.hypot(bench.world.white_noise_asd_v(), quantization_asd(a.input_range_v, a.bits, a.max_sample_rate_hz))
    finally:
        bench.close()
    return math.sqrt(asd**2 * fs_hz / 2 + lsb_v**2 / 12)


def detections(rep, codes: np.ndarray, rng: np.random.Generator, sigma_codes: float, averages: int,
               trials: int, batch: int = 2000) -> dict[str, Any]:
    """Monte Carlo of the per-ramp detection (module doc, 3): trial t takes pixel t % n_pix's noiseless
    ``codes`` (n_pix, record) plus noise."""
    from lidard.dsp.detect.cfar import CfarSettings, cfar_detect_with
    from lidard.raw.spectrum import _ramp_power

    d = rep.dsp
    s = CfarSettings(method="os", pfa=d.ramp_pfa, max_detections=d.candidate_slots, window=d.window,
                     bin_range=d.bin_range, iq=d.iq, records=averages)
    miss = {"up": 0, "down": 0, "pixel": 0}
    margins: list[np.ndarray] = []
    for t0 in range(0, trials, batch):
        nb = min(batch, trials - t0)
        pix = np.arange(t0, t0 + nb) % codes.shape[0]
        rec = codes[pix][:, None, :] + rng.standard_normal((nb, averages, codes.shape[-1])) * sigma_codes
        found = np.ones(nb, bool)
        for name, start in (("up", 0), ("down", d.ramp_samples)):
            p = _ramp_power(rep, rec, None, None, start)
            det = cfar_detect_with(p, s)
            hit = ((np.abs(det.index - LINE_BIN) <= NEAR_BINS) & det.valid).any(axis=1)
            miss[name] += int((~hit).sum())
            found &= hit
            if name == "down":
                margins.append(_margin_db(p, d.ramp_pfa, averages))
        miss["pixel"] += int((~found).sum())
    m = np.concatenate(margins)
    k = miss["pixel"]
    lo, hi = _poisson_bounds(k)
    return {"averages": averages, "trials": trials, "misses": miss, "p_miss": k / trials,
            "p_miss_95": [lo / trials, hi / trials], "p_all_16": (1 - k / trials) ** 16,
            "p_all_16_95_low": (1 - hi / trials) ** 16,
            "down_margin_db": {"mean": float(m.mean()), "sd": float(m.std(ddof=1)), "min": float(m.min())}}


def _poisson_bounds(k: int) -> tuple[float, float]:
    """Two-sided 95 % confidence bounds of a Poisson mean from ``k`` events."""
    def cdf(mu: float, n: int) -> float:     # P(X <= n)
        term = total = math.exp(-mu)
        for i in range(1, n + 1):
            term *= mu / i
            total += term
        return total

    def solve(f, target: float) -> float:
        a, b = 0.0, 10.0 + 10.0 * k       # f falls with mu
        for _ in range(200):
            mid = 0.5 * (a + b)
            a, b = (mid, b) if f(mid) > target else (a, mid)
        return 0.5 * (a + b)

    low = 0.0 if k == 0 else solve(lambda mu: cdf(mu, k - 1), 0.975)   # P(X >= k) = 2.5 %
    high = solve(lambda mu: cdf(mu, k), 0.025)                          # P(X <= k) = 2.5 %
    return low, high


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--averages", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--trials", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=12345, help="the Monte Carlo's generator")
    ap.add_argument("--seeds", type=int, nargs="+", default=None,
                    help="instead: the test's scan at these bench seeds (at the first --averages)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if a.trials < 1 or any(L < 1 for L in a.averages):
        ap.error("--trials and --averages must be >= 1")
    if a.seeds is not None:
        seed_scans(a.seeds, a.averages[0], a.json)
        return 0
    from lidard.raw.capture import RawCapture
    from lidard.raw.replay import replay_dsp

    with tempfile.TemporaryDirectory() as tmp:
        clean = RawCapture(capture(Path(tmp) / "clean.zarr", 1, {**CHILD_ENV, **QUIET})[0])
        noisy = RawCapture(capture(Path(tmp) / "noisy.zarr", 2, CHILD_ENV)[0])
        rep = replay_dsp(clean.attrs)
        codes = clean.chunks(0, clean.n_chunks).channel("beat", clean.channels, 1)[:, 0].astype(np.float64)
        two = noisy.chunks(0, noisy.n_chunks).channel("beat", noisy.channels, 2).astype(np.float64)
    lsb = rep.lsb_v
    measured = float((two[:, 0] - two[:, 1]).std() / math.sqrt(2) * lsb)
    sigma = budget_sigma_v(float(clean.attrs["adc"]["sample_rate_hz"]), lsb)
    head = {"sigma_budget_v": sigma, "sigma_measured_v": measured, "ramp_pfa": rep.dsp.ramp_pfa,
            "pixels": int(codes.shape[0])}
    print(json.dumps(head) if a.json else
          f"sigma: budget {sigma:.4e} V, measured {measured:.4e} V ({measured / sigma - 1:+.2%}); "
          f"ramp pfa {rep.dsp.ramp_pfa:.3g}; {codes.shape[0]} pixels")
    rng = np.random.default_rng(a.seed)
    for L in a.averages:
        r = detections(rep, codes, rng, sigma / lsb, L, a.trials)
        if a.json:
            print(json.dumps(r))
        else:
            m = r["down_margin_db"]
            print(f"averages {L}: misses up {r['misses']['up']}, down {r['misses']['down']} of {a.trials}; "
                  f"P(miss) {r['p_miss']:.2e} (95 %: {r['p_miss_95'][0]:.2e}..{r['p_miss_95'][1]:.2e}); "
                  f"P(16 of 16) {r['p_all_16']:.6f} (>= {r['p_all_16_95_low']:.6f}); "
                  f"down margin {m['mean']:.2f} +- {m['sd']:.2f} dB (min {m['min']:.2f})")
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
