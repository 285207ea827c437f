"""End-to-end frame scaling: wall time against modelled hardware time as the work grows.

Every scan runs on one embedded simulated bench (``open_instrument(cfg, bench="embedded")``: the
world, synthesis, the FPGA/AWG/digitizer/controller wire protocols and the frame DSP are all inside
the timed region, as in ``benchmarks/frame.py``). The hardware time is the digitizer's trigger clock
(virtual clock of the FPGA model: settle + triggers per pixel x the 2 x 80 us triangle period of
§4.4.1), i.e. what the real instrument would take for the same frame.

Three sweeps, one bench, one linearization:

* pixels  1k .. 16k at 1 average, 2 m. fpsa128 has 96 bonded rows x 128 columns = 12,288 pixels,
  so larger frames revisit pixels (an explicit ``pattern="pixels"`` list cycling over the array);
* averages 1 .. 10 at a fixed pixel count, 2 m;
* maximum range 2 .. 150 m: the ADC rate follows the range (eq. 2-1, beat = 2 gamma d / c, times
  the oversampling of config.adc) and so does the record length, so fewer pixels are scanned at long
  ranges (a fixed sample budget per point). The scene is a flat wall at 0.7 x the maximum range.
  The first scan at a new record length pays one-off table builds in the DSP (timed separately,
  "first-scan overhead"); the figures are for a warm daemon.

The growth law is a least-squares line through (log x, log wall): wall ~ x^slope, with the slope's
standard error. Wall times are the best of ``repeats`` runs; the process CPU time (all threads of
this process, the embedded bench included) is given too, and fitted the same way, because other jobs
on a shared 2-core machine stretch wall time but not CPU time.

    python benchmarks/scaling.py [--quick]

``run_scaling(quick=False, repeats=2) -> dict`` is what ``python -m benchmarks`` calls.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import threading
import time

from lidard.dsp_pool import cpu_time  # the DSP worker processes' CPU is a scan's too

import numpy as np
from scipy import stats

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))   # `python benchmarks/scaling.py` too

from benchmarks.frame import peak_rss_mb, reset_peak_rss
from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import open_instrument
from lidard.instrument import ScanRequest
from lidard.instrument.scan_loop import phase_noise_on

FULL = {"pixels": (1024, 2048, 4096, 8192, 16384), "averages": (1, 2, 5, 10), "avg_pixels": 1024,
        "ranges_m": (2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 150.0), "samples_budget": 2.0e7,
        "range_pixels_max": 1024}
QUICK = {"pixels": (256, 512, 1024, 2048), "averages": (1, 2, 5), "avg_pixels": 128,
         "ranges_m": (2.0, 5.0, 10.0), "samples_budget": 2.0e5, "range_pixels_max": 128}


def fit_growth(x, y) -> dict:
    """wall ~ x^slope: least squares in log-log, slope with its standard error."""
    lx, ly = np.log(np.asarray(x, float)), np.log(np.asarray(y, float))
    r = stats.linregress(lx, ly)
    return {"slope": float(r.slope), "slope_stderr": float(r.stderr), "prefactor": float(math.exp(r.intercept)),
            "r2": float(r.rvalue ** 2)}


def fit_linear(x, y) -> dict:
    """y = a + b x, least squares on relative residuals (weights 1/y, so the small-x points count as much
    as the large ones); the largest residual relative to y says how well the line holds."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    b, a = np.polyfit(x, y, 1, w=1.0 / y)
    resid = y - (a + b * x)
    return {"intercept": float(a), "slope": float(b), "max_rel_residual": float(np.max(np.abs(resid) / y))}


def cycled_pixels(n: int, optics) -> tuple[tuple[int, int], ...]:
    """n pixels in raster order over the bonded array, wrapping around when n exceeds it."""
    rows = np.asarray(optics.bonded_rows, dtype=np.int64)
    rr, cc = np.meshgrid(rows, np.arange(optics.cols), indexing="ij")
    flat = np.stack([rr.ravel(), cc.ravel()], axis=1)
    idx = np.arange(n) % len(flat)
    return tuple((int(r), int(c)) for r, c in flat[idx])


def _wall_scene(distance_m: float) -> dict:
    return {"name": f"wall {distance_m:g} m", "target": [
        {"kind": "plane", "point": [0.0, 0.0, distance_m], "normal": [0.0, 0.0, -1.0], "reflectivity": 0.5}]}


class FrameRig:
    """One embedded bench + one linearization, reused by every scan of a sweep."""

    def __init__(self, cfg=None, scene_path: str | None = None) -> None:
        self.cfg = cfg or load_config(CONFIG_DIR / "sim.toml")
        t = time.perf_counter()
        self.inst = open_instrument(self.cfg, scene_path=scene_path, bench="embedded")
        try:
            self.cal = self.inst.linearize()
        except BaseException:
            self.inst.close()
            raise
        self.setup_s = time.perf_counter() - t

    @property
    def bench(self):
        # the embedded Bench owns the world: ground truth comes from it (as tests/e2e do)
        return self.inst._on_close.__self__

    def scan(self, pixels, averages: int = 1, max_range_m: float = 2.0, phase_noise: str | None = None):
        """(wall_s, ScanResult) of one scan of an explicit pixel list (``phase_noise``: the request's
        phase_noise_compensation, default the configuration's)."""
        req = ScanRequest(pattern="pixels", pixels=tuple(pixels), averages=int(averages), max_range_m=max_range_m,
                          phase_noise_compensation=phase_noise)
        t = time.perf_counter()
        res = self.inst.run_scan(req, lambda p: None, threading.Event(), self.cal)
        return time.perf_counter() - t, res

    def best_of(self, repeats: int, pixels, averages: int = 1, max_range_m: float = 2.0,
                phase_noise: str | None = None) -> dict:
        walls, cpus, rss = [], [], []
        for _ in range(max(1, repeats)):
            reset_peak_rss()
            c0 = cpu_time()
            wall, res = self.scan(pixels, averages, max_range_m, phase_noise)
            cpus.append(cpu_time() - c0)
            walls.append(wall)
            rss.append(peak_rss_mb())
        wall = min(walls)
        return {"pixels": len(pixels), "averages": int(averages), "max_range_m": float(max_range_m),
                "wall_s": wall, "cpu_s": min(cpus), "peak_rss_mb": max(rss), "hardware_s": float(res.hardware_time_s),
                "realtime_factor": float(res.hardware_time_s) / wall, "points": int(len(res.points)),
                "adc_rate_hz": float(res.meta["adc"]["sample_rate_hz"]),
                "record_length": int(res.meta["adc"]["record_length"]),
                "phase_noise": bool(res.meta["dsp"]["phase_noise_compensation"])}

    def close(self) -> None:
        self.inst.close()


def _per_pixel(r: dict, n: int) -> dict:
    r.update(wall_per_pixel_s=r["wall_s"] / n, cpu_per_pixel_s=r["cpu_s"] / n, hardware_per_pixel_s=r["hardware_s"] / n)
    return r


def run_scaling(quick: bool = False, repeats: int = 2, log=print) -> dict:
    sizes = QUICK if quick else FULL
    rig = FrameRig(scene_path=str(CONFIG_DIR / "scenes" / "cal_letters.toml"))
    out: dict = {"setup_s": rig.setup_s, "repeats": repeats}
    try:
        optics = rig.inst.optics
        rig.scan(cycled_pixels(16, optics))                              # warm the 2 m DSP tables
        rows = []
        for n in sizes["pixels"]:
            rows.append(rig.best_of(repeats, cycled_pixels(n, optics)))
            log(f"  pixels {n:6d}: wall {rows[-1]['wall_s']:.3f} s  hardware {rows[-1]['hardware_s']:.3f} s")
        out["pixels"] = {"rows": rows, "fit": fit_growth([r["pixels"] for r in rows], [r["wall_s"] for r in rows]),
                         "cpu_fit": fit_growth([r["pixels"] for r in rows], [r["cpu_s"] for r in rows]),
                         "cpu_affine": fit_linear([r["pixels"] for r in rows], [r["cpu_s"] for r in rows]),
                         "hw_fit": fit_growth([r["pixels"] for r in rows], [r["hardware_s"] for r in rows])}

        px = cycled_pixels(sizes["avg_pixels"], optics)
        rows = []
        for a in sizes["averages"]:
            rows.append(rig.best_of(repeats, px, averages=a))
            log(f"  averages {a:3d}: wall {rows[-1]['wall_s']:.3f} s  hardware {rows[-1]['hardware_s']:.3f} s")
        xs = [r["averages"] for r in rows]
        out["averages"] = {"rows": rows, "fit": fit_growth(xs, [r["wall_s"] for r in rows]),
                           "cpu_fit": fit_growth(xs, [r["cpu_s"] for r in rows]),
                           "cpu_affine": fit_linear(xs, [r["cpu_s"] for r in rows]),
                           "hw_linear": fit_linear(xs, [r["hardware_s"] for r in rows]),
                           "wall_linear": fit_linear(xs, [r["wall_s"] for r in rows])}

        # the growth law is of one workload: phase-noise compensation off at every range ("auto" turns
        # it on from 60 m, a second channel and its DSP: measured beside, as its own cost)
        rows, pn_rows = [], []
        for d in sizes["ranges_m"]:
            rig.inst.set_scene(_wall_scene(0.7 * d))
            t = time.perf_counter()
            _, first = rig.scan(cycled_pixels(4, optics), max_range_m=d, phase_noise="off")   # cold caches
            cold = time.perf_counter() - t
            n_rec = int(first.meta["adc"]["record_length"])
            n = int(np.clip(sizes["samples_budget"] // n_rec, 16, sizes["range_pixels_max"]))
            r = _per_pixel(rig.best_of(repeats, cycled_pixels(n, optics), max_range_m=d, phase_noise="off"), n)
            r["first_scan_overhead_s"] = cold
            rows.append(r)
            log(f"  range {d:6.1f} m: {r['adc_rate_hz'] / 1e6:7.2f} MS/s x {n_rec} samples, {n} pixels, "
                f"wall {r['wall_s']:.3f} s ({1e3 * r['wall_per_pixel_s']:.2f} ms/pixel), first scan {cold:.2f} s")
            if phase_noise_on(rig.cfg, ScanRequest(max_range_m=d)):
                rig.scan(cycled_pixels(4, optics), max_range_m=d)            # its tables, cold
                pn_rows.append(_per_pixel(rig.best_of(repeats, cycled_pixels(n, optics), max_range_m=d), n))
                log(f"    with phase-noise compensation (auto): {1e3 * pn_rows[-1]['wall_per_pixel_s']:.2f} ms/pixel")
        out["range"] = {"rows": rows, "pn_rows": pn_rows,
                        "fit_record": fit_growth([r["record_length"] for r in rows], [r["wall_per_pixel_s"] for r in rows]),
                        "cpu_affine_record": fit_linear([r["record_length"] for r in rows],
                                                        [r["cpu_per_pixel_s"] for r in rows]),
                        "cpu_fit_record": fit_growth([r["record_length"] for r in rows], [r["cpu_per_pixel_s"] for r in rows]),
                        "fit_range": fit_growth([r["max_range_m"] for r in rows], [r["wall_per_pixel_s"] for r in rows])}
    finally:
        rig.close()
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--repeats", type=int, default=2)
    args = ap.parse_args(argv)
    r = run_scaling(args.quick, args.repeats)
    for key, label in (("pixels", "pixels"), ("averages", "averages")):
        f = r[key]["fit"]
        print(f"wall ~ {label}^{f['slope']:.3f} +- {f['slope_stderr']:.3f} (r2 {f['r2']:.4f})")
    hl = r["averages"]["hw_linear"]
    print(f"hardware time = {hl['intercept']:.4f} s + {hl['slope']:.4f} s x averages "
          f"(max relative residual {100 * hl['max_rel_residual']:.2f} %)")
    f = r["range"]["fit_record"]
    print(f"wall per pixel ~ record_length^{f['slope']:.3f} +- {f['slope_stderr']:.3f}")


if __name__ == "__main__":
    main()
