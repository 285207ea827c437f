"""Switch self-test: every bonded row and every column of the FPSA toggled against the monitor tap.

The FPSA's switches are addressed by row and column lines (dissertation §4.3.1, §4.3.3: the HV583
outputs drive the MEMS actuators of one row and one column per beam), so a line stuck on or off shows
as a wrong number of emitting beams. One acquisition (:mod:`.acquisition`) steps a pattern of one
pixel per line; the digitizer's "tap" channel (a DC photodiode on the light leaving the chip) is
proportional to the number of beams, and :func:`analyse_selftest` turns the readings into stuck lines.
"""

from __future__ import annotations

from typing import Any
from collections.abc import Callable

import numpy as np

from ..config import Config
from .selftest_analysis import hv_pull_in_problem
from .acquisition import AcquisitionLifecycle, AcquisitionPlan
from .errors import InstrumentError
from .safety import SafetyMonitor

READ_STEP = 256              # segments per read (progress granularity)
TAP_RECORD_LENGTH = 64       # samples per tap reading (a DC level: a short record suffices)


def run_selftest(cfg: Config, optics, lifecycle: AcquisitionLifecycle, safety: SafetyMonitor,
                 drive_v: np.ndarray, progress: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:
    """Toggle every bonded row (partner: one fixed column) and every column (partner: one fixed
    row) through a pattern, one pixel per line, and read the monitor tap; see :func:`analyse_selftest`."""
    bonded = [int(r) for r in optics.bonded_rows]
    cols = list(range(int(optics.cols)))
    r0, c0 = bonded[len(bonded) // 2], cols[len(cols) // 2]
    pixels = np.array([(r, c0) for r in bonded] + [(r0, c) for c in cols], dtype=np.int64)
    n = len(pixels)
    fs = float(cfg.adc.min_sample_rate_hz) if cfg.adc.min_sample_rate_hz else 10e6
    plan = AcquisitionPlan(pixels, 1, ("tap",), fs, TAP_RECORD_LENGTH, 16)
    lsb = cfg.adc.input_range_v / 2 ** plan.bits
    if progress is not None:
        progress({"stage": "preparing", "lines": n})

    def measured(first: int, samples: np.ndarray) -> None:
        if progress is not None:
            progress({"stage": "measuring", "done": first + len(samples), "lines": n})

    safety.bring_up(check_hv=False)   # a low HV is diagnosed below, not refused
    try:
        hv_v = float(safety.controller.hv_v())
        acq = lifecycle.ready(plan, drive_v=drive_v)
        lifecycle.start(acq)
        volts = lifecycle.read_all(acq, READ_STEP, measured)[:, 0, :].astype(np.float64).mean(axis=1) * lsb
        reason = safety.check()
        if reason is not None:
            raise InstrumentError(f"self-test stopped: {reason}")
    finally:
        try:
            lifecycle.stop()
        finally:
            safety.bring_down()
    report = analyse_selftest(volts[:len(bonded)], volts[len(bonded):], bonded, cols, r0, c0)
    return with_hv_check(report, volts, hv_v, cfg.resolved.profile, lsb)


def with_hv_check(report: dict[str, Any], tap_v: np.ndarray, hv_v: float, profile, lsb_v: float) -> dict[str, Any]:
    """Add ``hv_v`` and ``hv_problem`` (None, or why dark lines come from an HV below pull-in,
    selftest_analysis.hv_pull_in_problem) to the report; a problem makes it not ok.

    A line is dark below half the single-beam level; with no line lit at all every line is dark."""
    v1 = report["single_beam_v"]
    dark_v = 0.5 * v1 if np.isfinite(v1) and v1 > 0 else float(np.max(tap_v, initial=0.0)) + lsb_v
    problem = hv_pull_in_problem(tap_v, hv_v, profile.pull_in_v, dark_v=dark_v,
                                 spread_v=profile.threshold_spread_v)
    return {**report, "ok": bool(report["ok"] and problem is None), "hv_v": hv_v, "hv_problem": problem}


def analyse_selftest(row_v: np.ndarray, col_v: np.ndarray, rows: list[int], cols: list[int],
                     r0: int, c0: int) -> dict[str, Any]:
    """Beam counts and stuck lines from the tap readings.

    Each reading becomes a beam count ``n = round(v / v1)`` with ``v1`` the single-beam level
    (median of the lowest cluster). A healthy line gives 1. A line reading 0 while its family
    reads >= 1 is stuck OFF. A stuck-ON line adds a beam to every OTHER measurement of its own
    family and of the other family, so the family reads 2 while the stuck line itself reads 1:
    a line reading fewer beams than its family's majority (but not 0) is stuck ON. A family that
    reads 0 throughout blames its fixed partner (stuck off).
    """
    row_v = np.asarray(row_v, np.float64)
    col_v = np.asarray(col_v, np.float64)
    v1 = _single_beam_v(np.concatenate([row_v, col_v]))
    stuck: list[dict[str, Any]] = []
    for fam, volts, lines, partner in (("row", row_v, rows, ("col", c0)), ("col", col_v, cols, ("row", r0))):
        stuck += _stuck_lines(fam, volts, lines, partner, v1)
    return {"ok": not stuck, "stuck": stuck, "single_beam_v": v1, "partner_row": int(r0), "partner_col": int(c0),
            "rows_tested": len(rows), "cols_tested": len(cols),
            "row_tap_v": [float(v) for v in row_v], "col_tap_v": [float(v) for v in col_v]}


def _single_beam_v(allv: np.ndarray) -> float:
    """Median of the lowest cluster of lit readings (NaN when nothing is lit)."""
    top = float(np.max(allv)) if allv.size else 0.0
    lit = allv[allv > 0.3 * top] if top > 0 else allv[:0]
    if lit.size == 0:
        return float("nan")
    return float(np.median(lit[lit < 1.5 * lit.min()]))


def _stuck_lines(fam: str, volts: np.ndarray, lines: list[int], partner: tuple[str, int],
                 v1: float) -> list[dict[str, Any]]:
    if not np.isfinite(v1) or v1 <= 0:
        n = np.zeros(len(volts), np.int64)
    else:
        n = np.rint(volts / v1).astype(np.int64)
    majority = int(np.bincount(np.clip(n, 0, None)).argmax()) if len(n) else 0
    if majority == 0:
        return [{"line": partner[0], "index": int(partner[1]), "state": "off",
                 "evidence": f"every {fam} read dark with this fixed partner"}]
    stuck = []
    for i, k in enumerate(n):
        if k == 0:
            stuck.append({"line": fam, "index": int(lines[i]), "state": "off",
                          "evidence": f"tap {volts[i]:.4g} V, no beam (family reads {majority})"})
        elif majority >= 2 and k < majority:
            stuck.append({"line": fam, "index": int(lines[i]), "state": "on",
                          "evidence": f"tap {volts[i]:.4g} V = {k} beam(s) while the other {fam}s read "
                                      f"{majority}: this line's extra beam is always there"})
    return stuck

