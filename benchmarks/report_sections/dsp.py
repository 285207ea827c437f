"""Report sections on the DSP of one ramp: speed against error of the estimator ladder (issue 3,
§2.4.2 CRLB) and the chirp linearization by ILC per laser preset (§2.2, Fig. 2-4; issue 15).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from benchmarks.report_tables import Section, _plt, need, save, table


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
        + "\n![speed vs error](img/speed_vs_error.png)\n")
    return s


ILC_PAPER = {"up": 140.0, "down": 600.0, "iterations": 14}


def _ilc_figure_and_rows(runs: list[dict], img: Path) -> tuple[str, list[list]]:
    """The convergence plot of every run (RMS nonlinearity / excursion per iteration, the dissertation's
    reductions marked) and one table row per run; returns the PNG's path in the report and the rows."""
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
    return png, rows


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
    png, rows = _ilc_figure_and_rows(runs, img)
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
        "the phases averaged (lidard.dsp.linearize.quadrature).\n\n"
        + table(["preset", "monitor", "plain triangle RMS / swing", "reduction up", "reduction down", "iterations",
                 "true residual up", "true residual down", "converged", "stop"], rows)
        + f"| dissertation §2.2 (Fig. 2-4) | real | | {ILC_PAPER['up']:.0f}x | {ILC_PAPER['down']:.0f}x | "
          f"{ILC_PAPER['iterations']} | | | | |\n"
        + f"\n![ILC convergence]({png})\n")
    return s
