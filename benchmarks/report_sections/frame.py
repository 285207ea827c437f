"""Report sections on the end-to-end frame (issue 7; issue 18): how wall, CPU and hardware time
scale with pixels, averages and range, and the reference CAL-letters frame against the limit
kernel of the same scan (each frame measured in its own process by ``benchmarks/frame.py``).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from benchmarks.machine import ROOT, machine_facts
from benchmarks.report_tables import Section, _plt, save, table


def sec_scaling(quick: bool, img: Path, log) -> Section:
    from benchmarks.scaling import run_scaling

    s = Section("scaling", "4. End-to-end frame: wall time against hardware time, and how it scales")
    r = run_scaling(quick, repeats=1 if quick else 2, log=log)
    png = _scaling_figure(r, img)

    hdr = ["pixels", "averages", "max range (m)", "ADC MS/s", "record", "hardware (s)", "wall (s)", "CPU (s)",
           "real-time factor", "points", "peak RSS (MB)"]
    aff = r["range"]["cpu_affine_record"]
    rr = r["range"]["rows"]
    law = _growth_laws(r)
    s.data = r

    def both(key, fit_key, cpu_key):
        f, c = r[key][fit_key], r[key][cpu_key]
        return (f"wall ~ x^{f['slope']:.2f} +- {f['slope_stderr']:.2f}; CPU ~ x^{c['slope']:.2f} +- "
                f"{c['slope_stderr']:.2f}")

    s.headline = [("frame time growth with pixels x (1 average, 2 m)", both("pixels", "fit", "cpu_fit"),
                   "issue 7: state the law"),
                  ("frame time growth with averages x (2 m)", both("averages", "fit", "cpu_fit"),
                   "issue 7: state the law"),
                  (f"time per pixel growth with record length x ({r['range']['rows'][0]['max_range_m']:g} -> "
                   f"{r['range']['rows'][-1]['max_range_m']:g} m max range)",
                   both("range", "fit_record", "cpu_fit_record")
                   + f"; CPU {1e3 * aff['intercept']:.2g} ms + {1e9 * aff['slope']:.3g} ns x samples",
                   "issue 7: state the law"),
                  ("peak RSS of the largest scans (during the scan, whole process)",
                   f"{r['pixels']['rows'][-1]['peak_rss_mb']:.0f} MB at {r['pixels']['rows'][-1]['pixels']:,} pixels "
                   f"x 1 average; {rr[-1]['peak_rss_mb']:.0f} MB at {rr[-1]['pixels']} pixels, {rr[-1]['max_range_m']:g} m",
                   "< 2 GB (the frame target)")]
    s.markdown = (
        "One embedded simulated bench (world, synthesis, the four wire protocols, frame DSP all inside the timed "
        "region), one linearization, explicit pixel lists (fpsa128 has 12,288 bonded pixels; larger frames revisit "
        "pixels). Hardware time = the digitizer's trigger clock on the FPGA model's virtual clock (settle + "
        "triggers x 160 us triangle period): the time the real instrument would take. Real-time factor = hardware / "
        f"wall (>= 1: the simulation keeps up). Best of {r['repeats']} runs; CPU = process CPU time (all threads), "
        f"robust to other jobs on the machine; peak RSS = the process's resident high-water mark during the scan "
        f"(reset before each scan, so it includes the bench and the interpreter). Bench start + linearization: {r['setup_s']:.2f} s. "
        "`benchmarks/scaling.py`.\n\n" + law
        + "\n**Pixels** (1 average, max range 2 m)\n\n" + table(hdr, _scaling_rows(r, "pixels"))
        + "\n**Averages**\n\n" + table(hdr, _scaling_rows(r, "averages"))
        + "\n**Maximum range** (a wall at 0.7 x the maximum range; the ADC rate and record length follow the range; "
          "fewer pixels at long range; first-scan overhead = one-off DSP tables at a new record length; beyond a "
          "few tens of metres the wall is below the detection threshold of the §4.4 link (1 mW out), so 'points' "
          "drops to zero: the cost does not depend on it). Phase-noise compensation is off in every row, so the "
          "law is of one workload; where `auto` turns it on (a second digitizer channel and its DSP) its cost is "
          "measured beside, below.\n\n"
        + table(hdr + ["ms/pixel wall", "first-scan overhead (s)"],
                [row + [q["wall_per_pixel_s"] * 1e3, q["first_scan_overhead_s"]]
                 for row, q in zip(_scaling_rows(r, "range"), r["range"]["rows"])])
        + _pn_rows(r["range"]) + f"\n![scaling]({png})\n")
    return s


def _scaling_figure(r: dict, img: Path) -> str:
    """Frame time against pixels and averages, and time per pixel against range (log-log, with the
    fitted laws); returns the PNG's path in the report."""
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(16, 5))
    for ax, key, xkey, xl in ((axes[0], "pixels", "pixels", "pixels (1 average, 2 m)"),
                              (axes[1], "averages", "averages", "averages")):
        rows = r[key]["rows"]
        x = np.array([q[xkey] for q in rows], float)
        for yk, mk, lab in (("wall_s", "o", "wall"), ("cpu_s", "^", "process CPU"), ("hardware_s", "s", "hardware (modelled)")):
            ax.loglog(x, [q[yk] for q in rows], mk + "-", label=lab)
        f = r[key]["fit"]
        ax.loglog(x, f["prefactor"] * x ** f["slope"], "k:", lw=0.8,
                  label=f"fit wall ~ x^{f['slope']:.2f}+-{f['slope_stderr']:.2f}")
        ax.set(xlabel=xl, ylabel="time per frame (s)")
        ax.legend(fontsize=7)
    rows = r["range"]["rows"]
    x = np.array([q["max_range_m"] for q in rows])
    axes[2].loglog(x, [q["wall_per_pixel_s"] * 1e3 for q in rows], "o-", label="wall per pixel")
    axes[2].loglog(x, [q["cpu_per_pixel_s"] * 1e3 for q in rows], "^-", label="CPU per pixel")
    axes[2].loglog(x, [q["hardware_per_pixel_s"] * 1e3 for q in rows], "s-", label="hardware per pixel")
    f = r["range"]["fit_range"]
    axes[2].loglog(x, 1e3 * f["prefactor"] * x ** f["slope"], "k:", lw=0.8,
                   label=f"fit wall ~ range^{f['slope']:.2f}+-{f['slope_stderr']:.2f}")
    axes[2].set(xlabel="maximum range (m)", ylabel="ms per pixel")
    axes[2].legend(fontsize=7)
    return save(fig, img, "scaling.png")


def _scaling_rows(r: dict, key: str, extra=()) -> list[list]:
    """One table row per scan of the sweep ``key`` (pixels, averages or range)."""
    return [[q["pixels"], q["averages"], q["max_range_m"], f"{q['adc_rate_hz'] / 1e6:.2f}", q["record_length"],
             q["hardware_s"], q["wall_s"], q["cpu_s"], q["realtime_factor"], q["points"], f"{q['peak_rss_mb']:.0f}"]
            + [q[e] for e in extra] for q in r[key]["rows"]]


def _growth_laws(r: dict) -> str:
    """The paragraph stating the measured growth laws (log-log slopes) and the affine CPU-time laws,
    with the record length below which the fixed per-pixel cost dominates."""
    fp, fa, frr, frg = r["pixels"]["fit"], r["averages"]["fit"], r["range"]["fit_record"], r["range"]["fit_range"]
    hl = r["averages"]["hw_linear"]
    aff = r["range"]["cpu_affine_record"]
    n_x = aff["intercept"] / aff["slope"] if aff["slope"] > 0 else float("inf")   # fixed = per-sample part
    rr = r["range"]["rows"]
    if n_x <= rr[0]["record_length"]:
        where = "shorter than every record of this sweep"
    elif n_x >= rr[-1]["record_length"]:
        where = "longer than every record of this sweep"
    else:
        where = (f"max range below about "
                 f"{float(np.interp(n_x, [q['record_length'] for q in rr], [q['max_range_m'] for q in rr])):.0f} m")
    law = (f"**Growth laws measured** (least squares in log-log, slope +- standard error): wall time ~ pixels^"
           f"{fp['slope']:.2f} +- {fp['slope_stderr']:.2f} (CPU ~ pixels^{r['pixels']['cpu_fit']['slope']:.2f} +- "
           f"{r['pixels']['cpu_fit']['slope_stderr']:.2f}); wall ~ averages^{fa['slope']:.2f} +- {fa['slope_stderr']:.2f} "
           f"(hardware time = {hl['intercept']:.3g} s + {hl['slope']:.3g} s x averages, linear to "
           f"{100 * hl['max_rel_residual']:.2f} %); wall per pixel ~ record length^{frr['slope']:.2f} +- "
           f"{frr['slope_stderr']:.2f} (CPU ~ record length^{r['range']['cpu_fit_record']['slope']:.2f} +- "
           f"{r['range']['cpu_fit_record']['slope_stderr']:.2f}) ~ range^{frg['slope']:.2f} +- {frg['slope_stderr']:.2f}. Read as affine laws "
           f"(CPU time): a frame costs {r['pixels']['cpu_affine']['intercept']:.3g} s + "
           f"{1e3 * r['pixels']['cpu_affine']['slope']:.3g} ms x pixels at 2 m; a {r['averages']['rows'][0]['pixels']}-"
           f"pixel frame costs {r['averages']['cpu_affine']['intercept']:.3g} s + "
           f"{r['averages']['cpu_affine']['slope']:.3g} s x averages (the intercept is the per-pixel work that does not repeat per chirp); a pixel "
           "costs "
           f"{1e3 * r['range']['cpu_affine_record']['intercept']:.3g} ms + "
           f"{1e9 * r['range']['cpu_affine_record']['slope']:.3g} ns x record samples (largest residual "
           f"{100 * r['range']['cpu_affine_record']['max_rel_residual']:.0f} %): the fixed per-pixel part dominates "
           f"records shorter than {n_x:,.0f} samples ({where}); beyond that the cost grows linearly with the record "
           "length, i.e. with the range.\n")
    return law


def sec_frame(quick: bool, img: Path, log) -> Section:
    s = Section("frame", "4b. The reference frame (CAL letters)")
    shapes = [((40, 56), (40, 72), 2)] if quick else \
        [((0, 128), (0, 128), 10), ((0, 128), (0, 128), 1)]
    rows, runs = [], []
    for r_, c_, avg in shapes:
        # its own process: the peak RSS is then this frame's, not the high-water mark of the report
        proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "frame.py"), "--json", "--limit", "--averages", str(avg),
                               "--rows", f"{r_[0]}:{r_[1]}", "--cols", f"{c_[0]}:{c_[1]}"], cwd=ROOT,
                              capture_output=True, text=True, timeout=1800)
        if proc.returncode != 0:
            raise RuntimeError(f"benchmarks/frame.py failed: {proc.stderr.strip().splitlines()[-1:]}")
        f = json.loads(proc.stdout.strip().splitlines()[-1])
        runs.append(f)
        rows.append([f["pixels"], avg, f["hardware_s"], f["wall_s"], f["cpu_s"], f"{f['realtime_factor']:.2f}",
                     f"{f['realtime_factor_cpu']:.2f}", f["linearization_wall_s"], f"{f['peak_rss_mb']:.0f}"])
        log(f"  {f['pixels']} px x {avg} avg: hardware {f['hardware_s']:.2f} s wall {f['wall_s']:.2f} s")
    s.data = {"runs": runs}
    f0 = runs[0]
    s.headline = [_limit_headline(f, facts=machine_facts()) for f in runs] + [(f"real-time factor, {f0['pixels']} pixels x {f0['averages']} averages (CAL letters, 2 m)",
                   f"{f0['realtime_factor']:.2f} on wall time ({f0['realtime_factor_cpu']:.2f} on process CPU time)",
                   ">= 1"),
                  ("peak RSS of that frame (own process: bench, daemon side, DSP)", f"{f0['peak_rss_mb']:.0f} MB",
                   "< 2 GB")]
    s.markdown = (
        "`benchmarks/frame.py`, one process per frame (so the peak RSS is the frame's own): a fresh embedded bench, "
        "default profile (fpsa128, 25 mm lens) and chirp, CAL scene, max range 2 m (ADC "
        f"{f0['adc_rate_hz'] / 1e6:g} MS/s, {f0['record_length']:,} samples per trigger), "
        "16-bit records. Real-time factor = hardware frame time / wall "
        "time; on CPU time it is what an unloaded machine would reach (the scan runs on one thread; other jobs "
        "on a shared machine stretch wall time only).\n\n"
        + table(["pixels", "averages", "hardware frame time (s)", "wall (s)", "CPU (s)", "real-time factor (wall)",
                 "real-time factor (CPU)", "linearization wall (s)", "peak RSS (MB)"], rows)
        + "\nAgainst the limit kernel of the same scan (`benchmarks/limit.py`, run in the same process right "
        "after it: the same samples synthesized as cos + noise -> int16, one copy, one windowed rfft + argmax "
        "per ramp, the points written as PLY), per stage on the scan thread's CPU time (wall time in "
        "brackets; wall stretches with other jobs on a shared machine):\n\n"
        + table(["pixels", "averages", "synthesis", "transport", "DSP", "points", "whole scan / whole limit"],
                [[f["pixels"], f["averages"]] + [f"{f['ratio_cpu'].get(k, float('nan')):.1f}x ({f['ratio_wall'].get(k, float('nan')):.1f}x)"
                                                 for k in ("synthesis", "transport", "dsp", "points")]
                 + [f"{f['ratio_scan_cpu']:.1f}x ({f['ratio_scan_wall']:.1f}x)"] for f in runs]))
    return s


def _pn_rows(rng: dict) -> str:
    """The range sweep's rows re-measured with phase-noise compensation on (where "auto" turns it on)."""
    pn = rng.get("pn_rows") or []
    if not pn:
        return ""
    off = {q["max_range_m"]: q for q in rng["rows"]}
    return ("\nWith phase-noise compensation (`auto`), same pixels:\n\n"
            + table(["max range (m)", "ms/pixel wall, compensated", "ms/pixel wall, off", "ratio (CPU)"],
                    [[q["max_range_m"], q["wall_per_pixel_s"] * 1e3, off[q["max_range_m"]]["wall_per_pixel_s"] * 1e3,
                      f"{q['cpu_per_pixel_s'] / off[q['max_range_m']]['cpu_per_pixel_s']:.2f}"] for q in pn]))


def _limit_headline(f: dict, facts: dict) -> tuple[str, str, str]:
    """One headline row: scan/limit per stage (CPU time) with the real-time factor and the machine."""
    r = {k: f["ratio_cpu"].get(k, float("nan")) for k in ("synthesis", "dsp", "transport", "points")}
    return (f"frame / limit kernel, {f['pixels']} px x {f['averages']} avg, on CPU time "
            f"({facts['cpus']} CPUs, {facts['cpu_model'] or 'cpu unknown'})",
            f"synthesis {r['synthesis']:.1f}x, DSP {r['dsp']:.1f}x, transport {r['transport']:.1f}x, "
            f"points {r['points']:.1f}x; whole scan {f['ratio_scan_cpu']:.1f}x; "
            f"real-time factor {f['realtime_factor_cpu']:.2f} (CPU), {f['realtime_factor']:.2f} (wall)",
            "<= 3x (10 avg), <= 4x (1 avg)")
