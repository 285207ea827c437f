"""Plots of a sweep summary: detection probability, range RMSE and velocity RMSE against distance.

One line per configuration (colour by the first swept key that varies, line style by the second);
the range panel also draws each configuration's Cramer-Rao bound (lidard.dsp.ranging.crlb, dotted) so that
the gap between the estimator and the bound is visible where the SNR is high. Errors are drawn only
where the detection probability is at least MIN_PD: below it an RMSE rests on a few detections. Uses the Agg backend:
no display needed on a cluster's login node.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path

_STYLES = ("-", "--", ":", "-.")
MIN_PD = 0.5


def _varying(summary: list[dict], keys: list[str]) -> list[str]:
    return [k for k in keys if len({str(g.get(k)) for g in summary}) > 1]


def plot_sweep(summary: list[dict], swept_keys: Iterable[str], path: str | Path, *, title: str = "") -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter

    keys = _varying(summary, list(swept_keys))
    by_cfg: dict[tuple, list[dict]] = {}
    for g in summary:
        by_cfg.setdefault((g["config_hash"], g["reflectivity"], g["velocity_mps"]), []).append(g)
    first = sorted({str(g.get(keys[0])) for g in summary}) if keys else [""]
    second = sorted({str(g.get(keys[1])) for g in summary}) if len(keys) > 1 else [""]
    cmap = plt.get_cmap("tab10")
    fig, axes = plt.subplots(1, 3, figsize=(15, 5.6))
    for groups in by_cfg.values():
        groups = sorted(groups, key=lambda g: g["distance_m"])
        g0 = groups[0]
        colour = cmap(first.index(str(g0.get(keys[0]))) % 10) if keys else cmap(0)
        style = _STYLES[second.index(str(g0.get(keys[1]))) % len(_STYLES)] if len(keys) > 1 else "-"
        label = ", ".join(f"{k}={g0.get(k)}" for k in keys) or "configuration"
        d = [g["distance_m"] for g in groups]
        axes[0].plot(d, [g["p_detect"] for g in groups], style, color=colour, marker=".", label=label)
        # an RMSE over a handful of lucky detections is noise: errors only where Pd >= MIN_PD
        firm = [g for g in groups if g["p_detect"] >= MIN_PD]
        df = [g["distance_m"] for g in firm]
        axes[1].plot(df, [g["range_rmse_m"] * 1e3 for g in firm], style, color=colour, marker=".")
        axes[1].plot(df, [g["crlb_range_m"] * 1e3 for g in firm], ":", color=colour, lw=0.8, alpha=0.7)
        axes[2].plot(df, [g["velocity_rmse_mps"] * 1e3 for g in firm], style, color=colour, marker=".")
    axes[0].set_ylabel("detection probability")
    axes[0].set_ylim(-0.03, 1.03)
    axes[1].set_ylabel(f"range RMSE (mm) where Pd >= {MIN_PD:g}; dotted: CRLB")
    axes[2].set_ylabel(f"velocity RMSE (mm/s) where Pd >= {MIN_PD:g}")
    for ax in axes:
        ax.set_xlabel("distance (m)")
        ax.grid(True, alpha=0.3)
    for ax in axes[1:]:
        if any(math.isfinite(v) and v > 0 for line in ax.get_lines() for v in line.get_ydata()):
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
            # label the 2s and 5s of each decade too: a range RMSE spans one or two decades here
            ax.yaxis.set_minor_formatter(FuncFormatter(
                lambda v, _pos: f"{v:g}" if f"{v:.0e}"[0] in "25" else ""))
    handles, labels = axes[0].get_legend_handles_labels()
    ncol = min(3, max(1, len(labels)))
    fig.legend(handles, labels, fontsize=8, loc="lower center", ncol=ncol, frameon=False)
    if title:
        fig.suptitle(title)
    rows = math.ceil(len(labels) / ncol)
    fig.tight_layout(rect=(0, min(0.4, 0.045 * rows + 0.02), 1, 1))
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
