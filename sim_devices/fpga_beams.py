"""Which beams leave the FPSA chip during capture windows, from the row and column switch banks
(§4.3.6: switch dynamics and ghost beams; §4.2.1: a pixel emits when its row and column are on).

A beam (row r, column c) carries the product of the two switches' optical transmissions; the
digitizer sees its mean over a capture window. During a transition the old row/column is still
partly on, so the windows see ghost beams exactly as the dynamics predict. This module finds them
for many windows at once (used by :meth:`sim_devices.fpga.FpgaSim.triggers`).
"""

from __future__ import annotations

import numpy as np

from .world.mems import SwitchBank, mean_path_transmission


def beams_in_windows(rows_bank: SwitchBank, cols_bank: SwitchBank, candidate_rows: np.ndarray,
                     n_cols: int, floor: float, t0: np.ndarray, t1: np.ndarray,
                     dwell: np.ndarray | None = None):
    """(window, row, col, transmission) of every beam above ``floor`` in each window [t0, t1].

    ``candidate_rows``: the rows that can pass light at all (bonded, or stuck on). ``dwell``
    (optional, one id per window, non-decreasing): windows with the same id belong to one pixel
    dwell. Candidate switches are then found once per dwell, over the dwell's whole span (a switch
    that may be lit in a window may be lit in any span containing it: levels are monotone between
    events and an ON command inside is caught), and the exact transmissions are computed per
    window for those candidates only (issue 18: the averages of a pixel no longer evaluate every
    switch each)."""
    if dwell is None:
        span0, span1, of = t0, t1, np.arange(t0.size)
    else:
        starts = np.flatnonzero(np.r_[True, dwell[1:] != dwell[:-1]])
        ends = np.r_[starts[1:], dwell.size]
        span0, span1 = np.minimum.reduceat(t0, starts), np.maximum.reduceat(t1, starts)
        of = np.repeat(np.arange(starts.size), ends - starts)   # window -> its span
    # (spans x switches) in one pass each: a Python loop over the 2 x 128 lines cost ~30 ms
    # per digitizer read
    row_lit = rows_bank.possibly_lit_many(candidate_rows, span0, span1, floor)
    col_lit = cols_bank.possibly_lit_many(np.arange(n_cols), span0, span1, floor)
    # candidate (span, row, col) beams, then every window of each span
    rk, ri = np.nonzero(row_lit)
    ck, cc = np.nonzero(col_lit)
    n = span0.size
    nc = np.bincount(ck, minlength=n)
    col_start = np.cumsum(nc) - nc
    rep = nc[rk]
    sk = np.repeat(rk, rep)
    pr = candidate_rows[np.repeat(ri, rep)]
    within = np.arange(sk.size) - np.repeat(np.cumsum(rep) - rep, rep)
    pc = cc[col_start[sk] + within]
    if dwell is None:
        pk = sk
    else:
        per_span = np.bincount(of, minlength=n)           # windows per span
        first_win = np.cumsum(per_span) - per_span
        rep_w = per_span[sk]
        beam = np.repeat(np.arange(sk.size), rep_w)
        pk = first_win[sk][beam] + (np.arange(beam.size) - np.repeat(np.cumsum(rep_w) - rep_w, rep_w))
        pr, pc = pr[beam], pc[beam]
        order = np.argsort(pk, kind="stable")             # window-major, as without dwells
        pk, pr, pc = pk[order], pr[order], pc[order]
    trans = mean_path_transmission(rows_bank, pr, cols_bank, pc, t0[pk], t1[pk])
    keep = trans > floor
    return pk[keep], pr[keep], pc[keep], trans[keep]
