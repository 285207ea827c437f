"""The one-command performance and accuracy report (issue 7): ``python -m benchmarks``.

Runs every benchmark in this folder in one process, one run per comparison (the variants of a
comparison are measured side by side in the same run, so their ratios survive a noisy shared
machine), and writes ``<out>/benchmarks.md`` (generated; tables, targets of issues 3 and 6, the
dissertation's figures) and PNG plots under ``<out>/img/``. The markdown is written to a temporary
file and renamed, so a failed run never leaves half a report.

    python -m benchmarks [--quick] [--out DIR] [--only SECTION ...] [--json FILE]

``--quick`` runs tiny sizes (the test and development); its figures are not conclusive. ``--out``
defaults to the repository's ``docs/``. Every section's wall time is printed and recorded. A
section whose provider is missing (another module not delivered yet) or that fails is written as
such in the report, named with the error, and the command exits with status 1.

BLAS is pinned to one thread (set before numpy loads, in ``benchmarks/__main__.py``), so every
figure here is per core unless stated.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import importlib
import json
import math
import os
import platform
import resource
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs"
C_M_PER_S = 299_792_458.0


class SectionUnavailable(RuntimeError):
    """A section's provider (a function another module must supply) is not there."""


@dataclass
class Section:
    key: str
    title: str
    markdown: str = ""
    data: dict = field(default_factory=dict)
    headline: list[tuple[str, str, str]] = field(default_factory=list)   # (what, measured, target)
    seconds: float = 0.0
    rss_mb: float = 0.0          # the report process's RSS high-water mark after this section
    error: str | None = None


# --------------------------------------------------------------------------------------------- helpers
def need(module: str, name: str) -> Callable:
    """benchmarks.<module>.<name>, or a SectionUnavailable that says what is missing."""
    try:
        mod = importlib.import_module(f"benchmarks.{module}")
    except ImportError as exc:
        raise SectionUnavailable(f"benchmarks/{module}.py cannot be imported: {exc}") from None
    fn = getattr(mod, name, None)
    if not callable(fn):
        raise SectionUnavailable(f"benchmarks/{module}.py has no function {name}() yet "
                                 f"(the stated interface of issue 7)")
    return fn


def fmt(x: Any, spec: str = ".3g") -> str:
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return f"{int(x):,}"
    if isinstance(x, (float, np.floating)):
        if not math.isfinite(float(x)):
            return "n/a"
        return format(float(x), spec)
    return str(x)


def table(header: list[str], rows: list[list[Any]]) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        out.append("| " + " | ".join(c if isinstance(c, str) else fmt(c) for c in r) + " |")
    return "\n".join(out) + "\n"


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save(fig, img_dir: Path, name: str) -> str:
    img_dir.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(img_dir / name, dpi=100)
    _plt().close(fig)
    return f"img/{name}"


def machine_facts() -> dict:
    import scipy

    model = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        if commit and dirty:
            commit += " + uncommitted changes"
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return {"date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
            "cpus": os.cpu_count(), "cpu_model": model, "python": platform.python_version(),
            "numpy": np.__version__, "scipy": scipy.__version__, "platform": platform.platform(),
            "commit": commit, "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "unset")}


# -------------------------------------------------------------------------------------------- sections
def sec_estimators(quick: bool, img: Path, log) -> Section:
    from benchmarks import speed_vs_error as sve

    s = Section("estimators", "1. Speed against error: the estimator ladder")
    tiny = {512: dict(trials=300, batch=2000), 4096: dict(trials=80, batch=300)} if quick else None
    out = sve.run_speed_vs_error(quick, img / "speed_vs_error.png", sizes=tiny)
    res = out["results"]
    rows = []
    for n, (st, times) in res.items():
        for m in sve.ESTIMATOR_NAMES:
            te, tp = times[m]
            rows.append([n, m + (" (default)" if m == out["default"] else ""), f"{1 / te:,.0f}", f"{1 / tp:,.0f}"]
                        + [f"{st[m][snr]['worst_ratio']:.3f}" for snr in sve.SNRS_DB]
                        + [f"{st[m][20]['bias']:.3f}", f"{st[m][10]['outliers']:.3f}"])
    d = res[512][1][out["default"]]
    worst20 = max(res[n][0][out["default"]][snr]["worst_ratio"] for n in res for snr in sve.SNRS_DB if snr >= 20)
    s.data = {"default": out["default"], "ramps_per_s_512": 1 / d[0], "pipeline_ramps_per_s_512": 1 / d[1],
              "worst_ratio_ge20db": worst20, "accuracy_met": out["accuracy_met"], "speed_met": out["speed_met"],
              "rows": rows}
    s.headline = [("default estimator RMSE / sqrt(CRLB), worst offset, >= 20 dB", f"{worst20:.3f}", "<= 1.1"),
                  ("default estimator ramps/s, N = 512, one core", f"{1 / d[0]:,.0f}", ">= 100,000")]
    s.markdown = (
        "Post-FFT SNR = on-bin peak power over noise power per bin; ratio = RMSE / sqrt(CRLB) at the worst of "
        f"{len(out['offsets'])} sub-bin offsets ({out['trials'][512]} / {out['trials'][4096]} trials per point at "
        f"N = 512 / 4096, each ratio +-{out['ratio_uncertainty']:.3f} at 2 sigma). Estimator-only and full-chain "
        "(Hann rFFT + argmax + estimator) throughput on one core. `benchmarks/speed_vs_error.py`.\n\n"
        + table(["N", "estimator", "ramps/s (estimator)", "ramps/s (chain)"]
                + [f"ratio @ {x} dB" for x in sve.SNRS_DB] + ["max bias/sqrt(CRLB) @ 20 dB", "outliers @ 10 dB"], rows)
        + f"\n![speed vs error](img/speed_vs_error.png)\n")
    return s


ILC_PAPER = {"up": 140.0, "down": 600.0, "iterations": 14}


def sec_ilc(quick: bool, img: Path, log) -> Section:
    s = Section("ilc", "2. Chirp linearization (ILC) per laser preset")
    convergence = need("ilc", "convergence")
    from lidard.config import load_lasers

    presets = ["dfb_default"] if quick else list(load_lasers())
    runs = []
    # issue 15: every preset with the dissertation's real monitor and with the quadrature one
    for p, quad in [(p, q) for q in ((False,) if quick else (False, True)) for p in presets]:
        t = time.perf_counter()
        r = convergence(p, seed=1, quadrature=quad)
        runs.append(r)
        log(f"  {p}{' (quadrature)' if quad else ''}: reduction {r['reduction_up']:.0f}x / {r['reduction_down']:.0f}x, "
            f"{r.get('updates', len(r['iterations']) - 1)} updates ({time.perf_counter() - t:.1f} s)")
    rows = []
    plt = _plt()
    fig, ax = plt.subplots(1, 1, figsize=(8, 5))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, r in enumerate(runs):
        exc = float(r["excursion_hz"])
        it = r["iterations"]
        k = np.arange(len(it))
        ax.semilogy(k, [x["up_rms_hz"] / exc for x in it], "-o", color=colors[i % len(colors)], ms=3,
                    label=f"{r['preset']}{' (IQ)' if r.get('quadrature') else ''} up")
        ax.semilogy(k, [x["down_rms_hz"] / exc for x in it], "--s", color=colors[i % len(colors)], ms=3,
                    label=f"{r['preset']}{' (IQ)' if r.get('quadrature') else ''} down")
        mon = "quadrature" if r.get("quadrature") else "real"
        rows.append([r["preset"], mon, f"{float(r['plain_nonlinearity_pct']):.2f} %", f"{r['reduction_up']:.0f}x",
                     f"{r['reduction_down']:.0f}x", r.get("updates", len(it) - 1), f"{r['true_residual_up']:.2e}",
                     f"{r['true_residual_down']:.2e}",
                     bool(r["converged"]), str(r.get("stop_reason", ""))])
    d0 = runs[0]["iterations"][0]
    e0 = float(runs[0]["excursion_hz"])
    # where the dissertation's reductions (140x up, 600x down after 14 iterations) would put the first preset
    ax.plot([ILC_PAPER["iterations"]] * 2, [d0["up_rms_hz"] / e0 / ILC_PAPER["up"], d0["down_rms_hz"] / e0 / ILC_PAPER["down"]],
            "k*", ms=9, label=f"dissertation: 140x / 600x at {ILC_PAPER['iterations']} (from {runs[0]['preset']}'s start)")
    ax.set(xlabel="iteration (0 = plain triangle)", ylabel="RMS nonlinearity over the ROI / excursion (MZI)",
           title="ILC convergence per laser preset")
    ax.axhline(5e-5, color="k", lw=0.8, ls=":", label="5e-5 (true-residual target)")
    ax.legend(fontsize=7, ncol=2)
    png = save(fig, img, "ilc_convergence.png")
    d = next((r for r in runs if r["preset"] == "dfb_default"), runs[0])
    s.data = {"runs": runs, "rows": rows}
    s.headline = [
        ("ILC reduction on dfb_default, up / down (MZI)",
         f"{d['reduction_up']:.0f}x / {d['reduction_down']:.0f}x in {d.get('updates', len(d['iterations']) - 1)} "
         f"iterations",
         ">= 600x both in <= 10 (dissertation: 140x / 600x in 14)"),
        ("ILC true residual / excursion, dfb_default", f"{max(d['true_residual_up'], d['true_residual_down']):.2g}",
         "<= 5e-5")]
    for quad in (False, True):
        # a preset that is already linear (ideal) has nothing to reduce: 1x is its right answer
        rs = [r for r in runs if bool(r.get("quadrature")) == quad and r.get("updates", 1) > 0]
        if rs:
            worst = min(min(r["reduction_up"], r["reduction_down"]) for r in rs)
            s.headline.append((f"ILC worst reduction over the {len(rs)} preset(s) with a nonlinearity, both ramps, "
                               f"{'quadrature' if quad else 'real'} monitor", f"{worst:.0f}x", ">= 1000x (issue 15)"))
    s.markdown = (
        "`benchmarks.ilc.convergence(preset, seed=1, quadrature=...)` per preset: RMS nonlinearity over the ROI as the daemon "
        "measures it through the monitor MZI, per iteration; the true residual (RMS over the ROI / excursion) comes "
        f"from the laser model's nu(t). Monitor MZI delay {runs[0].get('mzi_delay_s', float('nan')) * 1e9:.0f} ns; "
        "32 averaged periods per measurement, doubled (up to 2048, the instrument's MAX_AVERAGES) when the "
        "noise floor stops learning above 4e-6 of the excursion, as the instrument does. Monitor `real`: one photodiode (the dissertation's); "
        "`quadrature`: the same MZI read as I + jQ (`[monitor] quadrature`), each record's phase demodulated and "
        "the phases averaged (lidard.dsp.ilcquad).\n\n"
        + table(["preset", "monitor", "plain triangle RMS / swing", "reduction up", "reduction down", "iterations",
                 "true residual up", "true residual down", "converged", "stop"], rows)
        + f"| dissertation §2.2 (Fig. 2-4) | real | | {ILC_PAPER['up']:.0f}x | {ILC_PAPER['down']:.0f}x | "
          f"{ILC_PAPER['iterations']} | | | | |\n"
        + f"\n![ILC convergence]({png})\n")
    return s


def sec_phase_noise(quick: bool, img: Path, log) -> Section:
    s = Section("phase_noise", "3. Laser phase-noise compensation")
    detection_curves = need("phase_noise", "detection_curves")
    ranges = (30.0, 150.0) if quick else (15.0, 30.0, 50.0, 75.0, 100.0, 150.0, 200.0)
    r = detection_curves(ranges, tau_c_s=(0.64e-6, 0.1e-6), trials=2 if quick else 20, seed=1)
    curves = phase_noise_curves(r)
    plt = _plt()
    fig, (ax, axl) = plt.subplots(1, 2, figsize=(15, 5))
    ax_snr = ax.twinx()
    rows = []
    for i, c in enumerate(curves):
        col = f"C{i}"
        lab = f"tau_c {c['tau_c_s'] * 1e6:.2f} us"
        ax.plot(c["ranges_m"], c["pd_raw"], "--o", color=col, label=f"{lab}, raw")
        ax.plot(c["ranges_m"], c["pd_comp"], "-s", color=col, label=f"{lab}, compensated")
        ax_snr.plot(c["ranges_m"], c["snr_db"], ":", color=col, lw=1, label=f"{lab}, link-budget SNR")
        axl.plot(c["ranges_m"], c["loss_raw_db"], "--o", color=col, label=f"{lab}, raw")
        axl.plot(c["ranges_m"], c["loss_comp_db"], "-s", color=col, label=f"{lab}, compensated")
        for j, d in enumerate(c["ranges_m"]):
            rows.append([f"{c['tau_c_s'] * 1e6:.2f}", f"{d:g}", f"{2 * d / C_M_PER_S / c['tau_c_s']:.1f}",
                         f"{c['pd_raw'][j]:.2f}", f"{c['pd_comp'][j]:.2f}"]
                        + [fmt(c[k][j], ".1f") for k in ("loss_raw_db", "loss_comp_db", "max_loss_comp_db", "snr_db")])
    ax.set(xlabel="range (m)", ylabel="detection probability", title="Pd with and without MZI compensation",
           ylim=(-0.05, 1.05))
    ax_snr.set_ylabel("link-budget SNR, Table 2-2 set-up (dB, dotted)")
    ax.legend(fontsize=8, loc="center left")
    axl.axhline(3.0, color="k", lw=0.8, ls=":", label="3 dB")
    axl.set(xlabel="range (m)", ylabel="mean peak loss vs zero linewidth (dB)", title="peak loss")
    axl.legend(fontsize=8)
    png = save(fig, img, "phase_noise_pd.png")
    s.data = {"raw": r, "curves": curves}
    hard = min(curves, key=lambda c: c["tau_c_s"])
    j = len(hard["ranges_m"]) - 1
    # issue 3: within 3 dB of zero linewidth where tau_c <= tau / 6
    deep = [(c["loss_comp_db"][k], c["loss_raw_db"][k]) for c in curves for k, d in enumerate(c["ranges_m"])
            if c["tau_c_s"] <= 2 * d / C_M_PER_S / 6]
    s.headline = [(f"Pd raw -> compensated, tau_c {hard['tau_c_s'] * 1e6:.2f} us at {hard['ranges_m'][j]:g} m",
                   f"{hard['pd_raw'][j]:.2f} -> {hard['pd_comp'][j]:.2f}", "a target the raw spectrum misses is detected")]
    if deep:
        s.headline.append(("worst mean peak loss vs zero linewidth where tau_c <= tau/6, raw -> compensated",
                           f"{max(x[1] for x in deep):.1f} dB -> {max(x[0] for x in deep):.1f} dB", "<= 3 dB"))
    s.markdown = (
        "`benchmarks.phase_noise.detection_curves(ranges_m, tau_c_s=(0.64e-6, 0.1e-6), ...)`: detection probability "
        "without and with compensation from the monitor MZI (§2.3, Fig. 2-6), peak loss against a zero-linewidth "
        "laser, and the link-budget SNR at each range (§2.4.1).\n\n"
        + f"Monitor MZI {r['mzi_delay_s'] * 1e9:.0f} ns, {r['trials']} trials per point, target at the nearest "
          "M tau_m.\n\n"
        + table(["tau_c (us)", "range (m)", "tau / tau_c", "Pd raw", "Pd compensated", "peak loss raw (dB)",
                 "peak loss compensated (dB)", "worst compensated (dB)", "link-budget SNR (dB)"], rows)
        + f"\n![phase-noise Pd]({png})\n"
        + _any_range_markdown(quick, img, s))
    return s


def _any_range_sweep(quick: bool) -> tuple[dict, str]:
    """quick: the ends and two off-grid ranges (75 m is half-way between 2 and 3 monitor delays); full:
    the quadrature monitor (the set-up that must hold everywhere) at 1 m steps, the other two at 5 m."""
    loss_sweep = need("phase_noise", "loss_sweep")
    if quick:
        return loss_sweep((15.0, 75.0, 137.3, 200.0), trials=2), "15, 75, 137.3 and 200 m (quick)"
    r = loss_sweep(np.arange(15.0, 200.0 + 1e-9, 1.0), methods=("quadrature",), trials=4)
    coarse = loss_sweep(np.arange(15.0, 200.0 + 1e-9, 5.0), methods=("grid", "short"), trials=4)
    for c in coarse["curves"]:
        c["ranges_m"] = coarse["ranges_m"]
    r["curves"] += coarse["curves"]
    return r, "every range from 15 to 200 m in 1 m steps (quadrature; 5 m steps for the other two)"


def _any_range_markdown(quick: bool, img: Path, s: Section) -> str:
    """Issue 15: the 15-200 m sweep at the TRUE ranges, three monitor set-ups, both linewidths."""
    r, steps = _any_range_sweep(quick)
    trials = r["trials"]
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(15, 5), sharey=True)
    rows = []
    for ax, tau_c in zip(axes, sorted({c["tau_c_s"] for c in r["curves"]})):
        for i, c in enumerate(x for x in r["curves"] if x["tau_c_s"] == tau_c):
            xs = c.get("ranges_m", r["ranges_m"])
            ax.plot(xs, c["mean_db"], "-", color=f"C{i}", label=f"{c['method']}, mean")
            ax.plot(xs, c["max_db"], ":", color=f"C{i}", lw=0.8, label=f"{c['method']}, worst trial")
            rows.append([f"{tau_c * 1e6:.2f}", c["method"], fmt(c["worst_mean_db"], ".2f"), f"{c['worst_mean_at_m']:g}",
                         fmt(float(np.mean(c["mean_db"])), ".2f"), fmt(max(c["max_db"]), ".2f"),
                         "yes" if c["worst_mean_db"] <= 3.0 else "no"])
        ax.axhline(3.0, color="k", lw=0.8, ls="--")
        ax.set(xlabel="true range (m)", title=f"tau_c {tau_c * 1e6:.2f} us", yscale="symlog")
        ax.legend(fontsize=8)
    axes[0].set_ylabel("peak loss vs zero linewidth (dB)")
    png = save(fig, img, "phase_noise_any_range.png")
    # per range: mean loss of every curve on the coarsest grid that all of them share
    grid_m = min((c.get("ranges_m", r["ranges_m"]) for c in r["curves"]), key=len)
    per_range = [[f"{d:g}"] + [fmt(dict(zip(c.get("ranges_m", r["ranges_m"]), c["mean_db"])).get(d, float("nan")), ".2f")
                               for c in r["curves"]] for d in grid_m]
    heads = ["range (m)"] + [f"{c['method']}, tau_c {c['tau_c_s'] * 1e6:.2f} us" for c in r["curves"]]
    s.data["any_range"] = r
    for c in r["curves"]:
        if c["method"] == "quadrature":
            s.headline.append((f"worst mean peak loss 15-200 m, quadrature monitor, tau_c {c['tau_c_s'] * 1e6:.2f} us",
                               f"{c['worst_mean_db']:.2f} dB", "<= 3 dB at every range"))
    return (
        f"\n**Any range (issue 15).** `benchmarks.phase_noise.loss_sweep`: {steps} at its TRUE round trip, {trials} trials each, the monitor with its own noise "
        f"({r['monitor_noise_v'] * 1e3:.0f} mV rms shot + RIN, {r['monitor_bits']}-bit ADC). `grid`: the "
        f"dissertation's single real MZI ({r['mzi_delay_s'] * 1e9:.0f} ns), nearest multiple of its delay: exact "
        f"only on that grid, the residual phi(t - M tau_m) - phi(t - tau) elsewhere. `short`: one real MZI of "
        f"{r['short_delay_s'] * 1e9:.0f} ns << tau_c summed the same way: its fringe (2 MHz) is too slow to "
        f"demodulate the laser's phase noise, which spreads far wider. `quadrature`: the "
        f"{r['mzi_delay_s'] * 1e9:.0f} ns MZI read in quadrature (`[monitor] quadrature = true`, a second "
        f"digitizer channel): the laser phase rebuilt per sample (lidard.dsp.pnrecon), every bin compensated at "
        f"its own round trip.\n\n"
        + table(["tau_c (us)", "monitor", "worst mean loss (dB)", "at (m)", "mean over ranges (dB)",
                 "worst single trial (dB)", "<= 3 dB everywhere"], rows)
        + f"\n![phase-noise loss at any range]({png})\n\nMean peak loss (dB) per range:\n\n"
        + table(heads, per_range))


def phase_noise_curves(r: dict) -> list[dict]:
    """Normalize detection_curves()'s dict to one list entry per coherence time."""
    need_keys = ("ranges_m", "curves")
    if not all(k in r for k in need_keys):
        raise SectionUnavailable(f"detection_curves() returned keys {sorted(r)}; the report expects "
                                 f"{list(need_keys)} (curves: one dict per tau_c)")
    ranges = [float(x) for x in r["ranges_m"]]
    snr = r.get("snr_db", r.get("budget_snr_db", [float("nan")] * len(ranges)))
    out = []
    for c in r["curves"]:
        out.append({"tau_c_s": float(c["tau_c_s"]), "ranges_m": ranges,
                    "pd_raw": [float(x) for x in c["pd_raw"]], "pd_comp": [float(x) for x in c["pd_comp"]],
                    "loss_raw_db": [float(x) for x in c.get("loss_raw_db", [np.nan] * len(ranges))],
                    "loss_comp_db": [float(x) for x in c.get("loss_comp_db", [np.nan] * len(ranges))],
                    "max_loss_comp_db": [float(x) for x in c.get("max_loss_comp_db", [np.nan] * len(ranges))],
                    "snr_db": [float(x) for x in c.get("snr_db", snr)]})
    return out


def sec_scaling(quick: bool, img: Path, log) -> Section:
    from benchmarks.scaling import run_scaling

    s = Section("scaling", "4. End-to-end frame: wall time against hardware time, and how it scales")
    r = run_scaling(quick, repeats=1 if quick else 2, log=log)
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
    png = save(fig, img, "scaling.png")

    def rowsof(key, extra=()):
        return [[q["pixels"], q["averages"], q["max_range_m"], f"{q['adc_rate_hz'] / 1e6:.2f}", q["record_length"],
                 q["hardware_s"], q["wall_s"], q["cpu_s"], q["realtime_factor"], q["points"], f"{q['peak_rss_mb']:.0f}"]
                + [q[e] for e in extra] for q in r[key]["rows"]]

    hdr = ["pixels", "averages", "max range (m)", "ADC MS/s", "record", "hardware (s)", "wall (s)", "CPU (s)",
           "real-time factor", "points", "peak RSS (MB)"]
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
        + "\n**Pixels** (1 average, max range 2 m)\n\n" + table(hdr, rowsof("pixels"))
        + "\n**Averages**\n\n" + table(hdr, rowsof("averages"))
        + "\n**Maximum range** (a wall at 0.7 x the maximum range; the ADC rate and record length follow the range; "
          "fewer pixels at long range; first-scan overhead = one-off DSP tables at a new record length; beyond a "
          "few tens of metres the wall is below the detection threshold of the §4.4 link (1 mW out), so 'points' "
          "drops to zero: the cost does not depend on it). Phase-noise compensation is off in every row, so the "
          "law is of one workload; where `auto` turns it on (a second digitizer channel and its DSP) its cost is "
          "measured beside, below.\n\n"
        + table(hdr + ["ms/pixel wall", "first-scan overhead (s)"],
                [row + [q["wall_per_pixel_s"] * 1e3, q["first_scan_overhead_s"]]
                 for row, q in zip(rowsof("range"), r["range"]["rows"])])
        + _pn_rows(r["range"]) + f"\n![scaling]({png})\n")
    return s


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


def sec_accuracy(quick: bool, img: Path, log) -> Section:
    """The end-to-end accuracy figures of tests/e2e, measured (not asserted) on embedded benches."""
    import threading

    from lidard.config import CONFIG_DIR, load_config
    from lidard.instrument import open_instrument
    from lidard.instrument import ScanRequest
    from sim_devices.world.scene import Scene

    s = Section("accuracy", "4c. Accuracy on the simulated bench (the scenes of tests/e2e)")
    scenes = CONFIG_DIR / "scenes"

    def scan(inst, req, cal):
        return inst.run_scan(req, lambda p: None, threading.Event(), cal)

    rows = []
    nominal = {"LIDARD__SIM__TOLERANCES__ENABLED": "false"}   # the hidden tolerances: benchmarks/tolerances.py
    inst = open_instrument(load_config(CONFIG_DIR / "sim.toml", environ=nominal), scene_path=str(scenes / "cal_letters.toml"),
                           bench="embedded")
    try:
        bench = inst._on_close.__self__        # the embedded Bench: ground truth comes from its world
        cal = inst.linearize()
        res = scan(inst, ScanRequest(pattern="roi", rows=(40, 56), cols=(40, 72), max_range_m=2.0), cal)
        pts = res.points[res.points["valid"] == 1]
        # a mixed pixel (issue 15) is scored against its footprint's surface nearest the point
        err = pts["range"] - bench.ground_truth(pts["row"], pts["col"], measured_m=pts["range"])
        letters = {"pixels": res.pixels_planned, "ranged": int(len(np.unique(pts["row"] * 4096 + pts["col"]))),
                   "rms_m": float(np.sqrt(np.mean(err ** 2))), "max_m": float(np.max(np.abs(err))),
                   "snr_db_range": (float(np.min(pts["snr_db"])), float(np.max(pts["snr_db"])))}
        rows.append(["CAL letters, 12 x 32 ROI, 1 average",
                     f"RMS range error {1e3 * letters['rms_m']:.3f} mm, max {1e3 * letters['max_m']:.3f} mm, "
                     f"{letters['ranged']}/{letters['pixels']} pixels; beat SNR {letters['snr_db_range'][0]:.0f}-"
                     f"{letters['snr_db_range'][1]:.0f} dB", "<= 1 mm RMS (SNR: Fig. 4-32 ~28 dB)"])
        bench.set_scene(Scene.from_dict({"target": []}))
        res = scan(inst, ScanRequest(pattern="roi", rows=(0, 32), cols=(0, 32), max_range_m=2.0), cal)
        empty = {"pixels": res.pixels_planned, "valid_points": int(res.points["valid"].sum())}
        rows.append([f"empty scene, {empty['pixels']} pixels", f"{empty['valid_points']} valid points",
                     "none beyond the false-alarm rate (pfa 1e-6)"])
    finally:
        inst.close()
    # a moving box: 1.5 m/s at 4.5 m needs a 2 m/s Doppler allowance (see tests/e2e)
    cfg = load_config(CONFIG_DIR / "sim.toml", environ={**nominal, "LIDARD__SCAN__MAX_SPEED_MPS": "2.0"})
    inst = open_instrument(cfg, scene_path=str(scenes / "mixed.toml"), bench="embedded")
    try:
        bench = inst._on_close.__self__
        cal = inst.linearize()
        scene = bench.world.scene
        box = next(i for i, t in enumerate(scene.targets) if np.linalg.norm(t.velocity) > 0)
        px = inst.optics.bonded_pixels()
        on_box = px[scene.cast(inst.optics.directions(px[:, 0], px[:, 1]), max_hits=1).target_index[:, 0] == box]
        res = scan(inst, ScanRequest(pattern="pixels", pixels=tuple(map(tuple, on_box.tolist())), max_range_m=6.0), cal)
        pts = res.points[res.points["valid"] == 1]
        v_true = inst.optics.directions(pts["row"], pts["col"]) @ np.asarray(scene.targets[box].velocity)
        dv = pts["velocity"] - v_true
        moving = {"pixels": int(len(on_box)), "valid_points": int(len(pts)), "max_abs_dv_mps": float(np.max(np.abs(dv))),
                  "rms_dv_mps": float(np.sqrt(np.mean(dv ** 2))), "speed_mps": float(np.linalg.norm(scene.targets[box].velocity))}
        rows.append([f"moving box, {moving['speed_mps']:.1f} m/s, {moving['pixels']} pixels on it",
                     f"radial velocity error RMS {moving['rms_dv_mps'] * 1e3:.1f} mm/s, max "
                     f"{moving['max_abs_dv_mps'] * 1e3:.1f} mm/s ({moving['valid_points']} valid points)",
                     "every point within 0.05 m/s"])
    finally:
        inst.close()
    s.data = {"letters": letters, "empty": empty, "moving_box": moving}
    s.headline = [("CAL letters end to end (384-pixel ROI): RMS range error vs ray-cast truth",
                   f"{1e3 * letters['rms_m']:.3f} mm", "<= 1 mm"),
                  ("moving box: worst radial-velocity error", f"{moving['max_abs_dv_mps']:.3f} m/s", "<= 0.05 m/s")]
    s.markdown = ("The scenes of `tests/e2e/test_e2e_scan.py`, measured here (the tests assert the targets): "
                  "embedded bench, nominal (`[sim.tolerances]` off: `benchmarks/tolerances.py` measures the "
                  "hidden tolerances), ILC calibration first, all simulator effects on.\n\n"
                  + table(["scene", "measured", "target"], rows))
    return s


def sec_fidelity(quick: bool, img: Path, log) -> Section:
    from benchmarks.fidelity import run_fidelity

    s = Section("fidelity", "5. Simulator fidelity against cost")
    r = run_fidelity(quick, rounds=1 if quick else 3, log=log)
    plt = _plt()
    names = list(next(iter(r["scenes"].values()))["variants"])
    fig, axes = plt.subplots(1, 3, figsize=(18, 5))
    w = 0.8 / len(r["scenes"])
    for i, (sc, v) in enumerate(r["scenes"].items()):
        x = np.arange(len(names)) + i * w
        q = [v["variants"][n] for n in names]
        axes[0].bar(x, [e["cpu_ratio"] for e in q], w, label=sc)
        # no bar where nothing was ranged (log axis: NaN leaves a gap)
        axes[1].bar(x, [1e3 * e["rms_err_truth_m"] for e in q], w, label=sc)
        axes[2].bar(x, [100 * e["ranged_fraction"] for e in q], w, label=sc)
    for ax, yl in ((axes[0], "scan CPU time / all effects on"), (axes[1], "RMS range error vs ray-cast truth (mm)"),
                   (axes[2], "pixels ranged (%)")):
        ax.set_xticks(np.arange(len(names)) + 0.4 - w / 2, names, rotation=20, fontsize=8)
        ax.set_ylabel(yl)
        ax.legend(fontsize=8)
    axes[0].axhline(1.0, color="k", lw=0.8)
    axes[1].set_yscale("log")
    png = save(fig, img, "fidelity.png")
    parts = []
    for sc, v in r["scenes"].items():
        rows = []
        for n, q in v["variants"].items():
            rows.append([n, q["wall_s"], q["wall_ratio"], q["cpu_s"], q["cpu_ratio"], 100 * q["ranged_fraction"],
                         1e3 * q["rms_err_truth_m"], 1e3 * q["max_err_truth_m"],
                         "reference" if n == "all on" else 1e3 * q["rms_diff_vs_all_on_m"],
                         "reference" if n == "all on" else q["ranged_only_one_side"], q["extra_returns"]])
        parts.append(f"\n**{sc}** (max range {v['max_range_m']:g} m, {v['pixels']} pixels)\n\n"
                     + table(["variant", "wall (s)", "wall ratio", "CPU (s)", "CPU ratio", "pixels ranged (%)",
                              "RMS error vs truth (mm)", "max error vs truth (mm)", "RMS change vs all on (mm)",
                              "pixels ranged by only one", "extra returns"], rows))
    s.data = r
    s.markdown = (
        "Each effect of `lidard.config.Effects` switched off alone (and all together) on its own embedded bench, "
        f"interleaved over {r['rounds']} round(s) with the all-on bench; one calibration for all. Cost = best-of-rounds "
        "scan time and its ratio to all on; error = first valid return per pixel against the world's ray-cast "
        "truth and against the all-on scan. 'n/a' = no pixel ranged. With every effect off the spectrum has no "
        "noise floor, so the CFAR's noise estimate is window sidelobes and leakage and it reports some of them as "
        "valid returns ('extra returns'; they are nearer than the target, hence the metre-scale error of 'all off'): "
        "switching everything off is not a cheaper stand-in for the simulation. "
        + "".join(f"Not modelled: {k} ({v}). " for k, v in r["not_modelled"].items())
        + "`benchmarks/fidelity.py`.\n" + "".join(parts) + f"\n![fidelity]({png})\n")
    letters = r["scenes"].get("CAL letters", {}).get("variants", {}).get("all on")
    if letters:
        s.headline = [("CAL letters, all effects on: RMS range error vs ray-cast truth",
                       f"{1e3 * letters['rms_err_truth_m']:.3f} mm ({100 * letters['ranged_fraction']:.1f} % ranged)",
                       "<= 1 mm")]
    return s


def sec_load(quick: bool, img: Path, log) -> Section:
    s = Section("load", "6. Daemon latency under load")
    run_load = need("load", "run_load")
    clients, per = (5, 4) if quick else (50, 40)
    r = run_load(clients=clients, requests_per_client=per, seed=1)
    s.data = r
    s.headline = [(f"daemon latency, {r['clients']} clients x {per} requests during a scan",
                   f"p50 {r['p50_ms']:.1f} ms, p99 {r['p99_ms']:.1f} ms, {r['errors']} errors", "no errors")]
    s.markdown = ("`benchmarks.load.run_load(clients, requests_per_client, seed=1)`: concurrent clients polling "
                  "status and listing scans on loopback while a scan runs.\n\n"
                  + table(["clients", "requests", "errors", "p50 (ms)", "p99 (ms)"],
                          [[r["clients"], r["requests"], r["errors"], f"{r['p50_ms']:.1f}", f"{r['p99_ms']:.1f}"]]))
    return s


def sec_kernels(quick: bool, img: Path, log) -> Section:
    from benchmarks.pattern_upload import run_upload
    from benchmarks.raycast import run_raycast
    from benchmarks.synthesis import run_synthesis
    from benchmarks.chain_throughput import run_chain_throughput
    from benchmarks.usb_throughput import run_usb

    s = Section("kernels", "7. Simulator, DSP chain and transport kernels")
    rc = run_raycast(repeats=2 if quick else 9)
    sy = run_synthesis(repeats=1 if quick else 5, quick=quick)
    usb = run_usb(segments=100 if quick else 2000, per_read=64 if quick else 256)
    up = run_upload(repeat=1 if quick else 3)
    ch = run_chain_throughput(n=512, batch=4000 if quick else 20_000, repeats=2 if quick else 5)
    rows = [["ray casting, 16,384 rays x 20 mixed targets", f"{rc['mixed20']['rays_per_s'] / 1e6:.3f} M rays/s", ""],
            ["ray casting, CAL letters 128 x 96", f"{rc['cal_letters']['rays_per_s'] / 1e6:.3f} M rays/s", ""]]
    for q in sy["rows"]:
        rows.append([f"beat synthesis, {q['workload']} ({q['segments']} x {q['samples']} at {q['fs_hz'] / 1e6:.1f} MS/s), "
                     f"phase noise {'on' if q['phase_noise'] else 'off'}, quantize {'on' if q['quantize'] else 'off'}",
                     f"{q['msamples_per_s']:.1f} M samples/s per core", ""])
    for q in sy["mzi"]:
        rows.append([f"MZI-only capture (ILC), phase noise {'on' if q['phase_noise'] else 'off'}",
                     f"{q['msamples_per_s']:.1f} M samples/s per core", ""])
    rows.append([f"estimator chain (Hann FFT + OS-CFAR + {ch['estimator']}) against a plain Hann rFFT + argmax, "
                 f"N = 512, one core", f"{ch['chain_ramps_per_s']:,.0f} against {ch['plain_ramps_per_s']:,.0f} ramps/s: "
                 f"{ch['ratio']:.2f}", ">= 0.5 (issue 18)"])
    rows += [["digitizer through the simulated USB path, in-process", f"{usb['inproc_mb_s']:.0f} MB/s", ">= 200 MB/s"],
             ["same, USB bridge (server thread)", f"{usb['bridge_thread_mb_s']:.0f} MB/s", ""],
             ["same, bench in a subprocess (TCP)", f"{usb['bridge_subprocess_mb_s']:.0f} MB/s", ""],
             [f"{up['pixels']:,}-pixel pattern upload at {up['baud'] / 1e6:g} Mbaud",
              f"{up['pty']['host_to_fpga_B']:,} B, {up['pty']['overhead_pct']:.2f} % framing, "
              f"{1e3 * up['pty']['modelled_s']:.1f} ms modelled wire time, {1e3 * up['pty']['wall_median_s']:.2f} ms "
              f"wall through a pty", ""]]
    s.data = {"raycast": rc, "synthesis": sy, "usb": usb, "upload": up, "chain": ch}
    s.headline = [("digitizer transfer through the simulated USB path (in-process)", f"{usb['inproc_mb_s']:.0f} MB/s",
                   ">= 200 MB/s"),
                  ("estimator chain / plain FFT + argmax throughput, N = 512", f"{ch['ratio']:.2f}", ">= 0.5")]
    s.markdown = ("`benchmarks/raycast.py`, `synthesis.py` (median CPU time), `chain_throughput.py` (CPU, best of "
                  "repeats), `usb_throughput.py`, `pattern_upload.py`.\n\n" + table(["what", "figure", "target"], rows))
    return s


def sec_budget(quick: bool, img: Path, log) -> Section:
    from lidard.config import CONFIG_DIR, load_config
    from lidard.physics.budget import LinkParams, budget_report, max_range_m, shot_limited_ref_window_w

    s = Section("budget", "8. Link budget (§2.4.1, `lidard.physics.budget`)")
    lp = LinkParams.table_2_2()
    d_shot = max_range_m(lp, against="shot")
    lo, hi = shot_limited_ref_window_w(lp)
    sim = load_config(CONFIG_DIR / "sim.toml")
    rep = budget_report(sim.link_params(), 0.8)
    s.data = {"shot_crossing_m": d_shot, "ref_window_w": (lo, hi), "sim_snr_0p8m_db": rep["snr_db"]}
    s.markdown = table(["quantity", "computed", "dissertation"], [
        ["signal = shot noise (Table 2-2 parameters)", f"{d_shot:.1f} m", "Fig. 2-8: ~220 m"],
        ["shot-noise-limited reference window", f"{lo * 1e6:.2f} uW < P_ref < {hi * 1e6:.0f} uW",
         "eqs. 4-29, 4-33"],
        ["SNR at 0.8 m, config/sim.toml (§4.4 set-up, rho 0.1)", f"{rep['snr_db']:.1f} dB", "Fig. 4-32: ~28 dB"]])
    return s


def sec_tolerances(quick: bool, img: Path, log) -> Section:
    from benchmarks.tolerances import report_section

    s = Section("tolerances", "4d. The bench's hidden tolerances: nominal, uncalibrated, one at a time")
    s.markdown, s.data, s.headline = report_section(quick, log)
    return s


SECTIONS: dict[str, Callable[[bool, Path, Callable], Section]] = {
    "estimators": sec_estimators, "ilc": sec_ilc, "phase_noise": sec_phase_noise, "scaling": sec_scaling,
    "frame": sec_frame, "accuracy": sec_accuracy, "tolerances": sec_tolerances, "fidelity": sec_fidelity, "load": sec_load, "kernels": sec_kernels, "budget": sec_budget,
}


# ---------------------------------------------------------------------------------------------- report
def measured_sections(out: Path) -> str:
    """The reports measured by their own commands (``<out>/measured/*.md``, in file-name order), kept
    verbatim in every generated report: each says its command, machine and date; edit those files
    by hand when re-measuring, never the generated benchmarks.md."""
    files = sorted(Path(out, "measured").glob("*.md"))
    if not files:
        return ""
    head = ("\n# Measured by their own commands\n\n_Included verbatim from docs/measured/*.md (too long "
            "or too specialised for this run); each section names the command that reproduces it._\n")
    return head + "".join("\n" + f.read_text().rstrip() + "\n" for f in files)


def render(sections: list[Section], facts: dict, quick: bool, total_s: float, out: Path | None = None) -> str:
    head = [
        "# Benchmarks\n",
        f"_Generated by `python -m benchmarks{' --quick' if quick else ''}` on {facts['date_utc']} "
        f"(commit {facts['commit'] or 'unknown'}); do not edit by hand, re-run the command._\n",
        f"Machine: {facts['cpus']} CPUs ({facts['cpu_model']}), Python {facts['python']}, numpy {facts['numpy']}, "
        f"scipy {facts['scipy']}, {facts['platform']}; BLAS threads {facts['blas_threads']}. The machine is shared "
        "and noisy: read ratios measured side by side and orders of magnitude, not the last digit.\n",
    ]
    if quick:
        head.append("**--quick run: tiny sizes, figures not conclusive.**\n")
    head.append(f"Total run time {total_s / 60:.1f} min; per section (wall time, and the report process's peak "
                "RSS so far, which only grows): "
                + ", ".join(f"{s.key} {s.seconds:.0f} s ({s.rss_mb:.0f} MB)" for s in sections) + ".\n")
    hl = [[w, m, t] for s in sections for (w, m, t) in s.headline]
    head.append("\n## Headline figures\n\n" + table(["what", "measured", "target"], hl))
    failed = [s for s in sections if s.error]
    if failed:
        head.append("\n**Sections not run:** " + "; ".join(f"{s.key}: {s.error}" for s in failed) + "\n")
    body = []
    for s in sections:
        body.append(f"\n## {s.title}\n\n")
        body.append(f"_Not run: {s.error}_\n" if s.error else s.markdown)
    return "\n".join(head) + "".join(body) + SEE_ALSO + (measured_sections(out) if out is not None else "")


# Reports measured by their own commands (too long for this run); kept in every generated report.
SEE_ALSO = """
## See also: design sweeps and scale-out on Dask

Detection probability, range and velocity RMSE against distance for 3 lasers x 3 powers (3,600 tasks
through `lidarctl sweep`), the scheduling overhead per task, throughput with 1 and 2 Dask worker
processes against in-process, and the model for 10 and 100 workers: [sweeps.md](sweeps.md)
(`python -m benchmarks.sweep_scale`; how to run on a cluster: [scale-out.md](scale-out.md)).
"""


def _jsonable(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return repr(o)


def run(quick: bool = False, out: Path = DEFAULT_OUT, only: list[str] | None = None, log=print,
        json_path: Path | None = None) -> dict:
    """Run the sections, write ``out/benchmarks.md``, ``out/img/*.png`` and (if asked) the figures as JSON."""
    out = Path(out)
    img = out / "img"
    img.mkdir(parents=True, exist_ok=True)
    facts = machine_facts()
    t_all = time.perf_counter()
    sections = []
    for key, fn in SECTIONS.items():
        if only and key not in only:
            continue
        log(f"[{key}] ...")
        t = time.perf_counter()
        try:
            sec = fn(quick, img, log)
        except SectionUnavailable as exc:
            sec = Section(key, key, error=str(exc))
        except Exception as exc:   # a broken section is reported, the others still run
            tb = traceback.format_exception_only(type(exc), exc)[-1].strip()
            sec = Section(key, key, error=f"failed: {tb}")
            traceback.print_exc()
        sec.seconds = time.perf_counter() - t
        sec.rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        sections.append(sec)
        log(f"[{key}] {'NOT RUN: ' + sec.error if sec.error else 'done'} ({sec.seconds:.1f} s)")
    total = time.perf_counter() - t_all
    text = render(sections, facts, quick, total, out)
    data = {"facts": facts, "quick": quick, "total_s": total,
            "sections": {s.key: {"seconds": s.seconds, "rss_mb": s.rss_mb, "error": s.error, "headline": s.headline, "data": s.data}
                         for s in sections}}
    # the JSON holds the same figures for tools and tests; every file is renamed into place
    files = [(out / "benchmarks.md", text)]
    if json_path is not None:
        files.insert(0, (Path(json_path), json.dumps(data, indent=1, default=_jsonable)))
    for path, content in files:
        tmp = path.with_name(f".{path.name}.tmp")
        tmp.write_text(content)
        os.replace(tmp, path)
    log(f"wrote {out / 'benchmarks.md'} and {len(list(img.glob('*.png')))} PNGs in {img} ({total / 60:.1f} min)")
    return {"sections": {s.key: s for s in sections}, "facts": facts, "total_s": total,
            "markdown": out / "benchmarks.md", "img": img}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes (tests, development); not conclusive")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (default: docs/)")
    ap.add_argument("--only", nargs="+", choices=list(SECTIONS), help="run only these sections")
    ap.add_argument("--json", type=Path, default=None, help="also write every figure as JSON to this file")
    args = ap.parse_args(argv)
    res = run(args.quick, args.out, args.only, json_path=args.json)
    bad = [k for k, s in res["sections"].items() if s.error]
    if bad:
        print(f"sections not run: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
