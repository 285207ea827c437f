"""Which beams leave the FPSA chip during capture windows, from the row and column switch banks
(§4.3.6: switch dynamics and ghost beams; §4.2.1: a pixel emits when its row and column are on).

A beam (row r, column c) carries the product of the two switches' optical transmissions; the
digitizer sees its mean over a capture window. During a transition the old row/column is still
partly on, so the windows see ghost beams exactly as the dynamics predict. This module finds them
for many windows at once (:func:`beams_in_windows`). :class:`ChipOptics` is held by
:class:`sim_devices.fpsa.device.FpgaSim` as ``fpga.optics`` and reads the board it is given
(:class:`~sim_devices.fpsa.board.FpsaBoard`): it builds the row and column switch banks from the
board's drive log (with the hold-level drive and the stuck switches; rebuilt when the board's
``revision`` moved), and answers which beams are lit in a window (:meth:`ChipOptics.lit_beams`) and
which triggers of a run see which beams (:meth:`ChipOptics.triggers`).
"""

from __future__ import annotations

import math

import numpy as np

from sim_devices.fpsa.board import FpsaBoard
from sim_devices.fpsa.drive_log import COL, ROW, with_holds
from sim_devices.fpsa.triggers import PixelSchedule, TriggerBatch
from sim_devices.world.mems import SwitchBank, mean_path_transmission, switch_thresholds


def beams_in_windows(rows_bank: SwitchBank, cols_bank: SwitchBank, candidate_rows: np.ndarray,
                     n_cols: int, floor: float, t0: np.ndarray, t1: np.ndarray,
                     dwell: np.ndarray | None = None):
    """(window, row, col, transmission) of every beam above ``floor`` in each window [t0, t1].

    ``candidate_rows``: the rows that can pass light at all (bonded, or stuck on). ``dwell``
    (optional, one id per window, non-decreasing): windows with the same id belong to one pixel
    dwell. Candidate switches are then found once per dwell, over the dwell's whole span (a switch
    that may be lit in a window may be lit in any span containing it: levels are monotone between
    events and an ON command inside is caught), and the exact transmissions are computed per
    window for those candidates only (the averages of a pixel no longer evaluate every
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


#: triggers computed per call at least (a digitizer read of the default scan is ~200): about ten
#: reads' worth. A call costs ~0.37 ms fixed + ~2.2 us a trigger here (a 20 x 128-pixel lit run with
#: the switch dynamics): the fixed part falls from ~40 % of a 200-trigger read's cost to ~8 %
TRIGGERS_AHEAD = 2048


class ChipOptics:
    """Switch banks, lit beams and triggers of the simulated FPSA chip, from its board's drive log.

    Not thread-safe on its own: the FPGA simulator calls it under its lock."""

    def __init__(self, board: FpsaBoard) -> None:
        self.board = board
        self.config = board.config
        self._banks: tuple[SwitchBank, SwitchBank] | None = None
        self._banks_revision = -1
        # (key, pattern, first trigger, block) of the last block of triggers computed (triggers())
        self._ahead: tuple[tuple, np.ndarray, int, TriggerBatch] | None = None

    def switch_banks(self) -> tuple[SwitchBank, SwitchBank]:
        """The row and column switch banks that follow the board's drive log as it is now."""
        board = self.board
        if self._banks is None or self._banks_revision != board.revision:
            kinds, lines, ts, vs = board.events.arrays()
            banks = []
            for k, n, dyn in ((ROW, self.config.rows, self.config.row_dynamics),
                              (COL, self.config.cols, self.config.col_dynamics)):
                ln, t, v = with_holds(k, kinds, lines, ts, vs, board.holds)
                # the drive events the switches actually follow (stuck ones ignore theirs)
                ln, t, v = board.stuck.apply(k, ln, t, v)
                thresholds = switch_thresholds(n, dyn, self.config.threshold_spread_v,
                                               [self.config.seed, 0x4B5, k])
                banks.append(SwitchBank(n, dyn, ln, t, v, thresholds=thresholds))
            self._banks = (banks[0], banks[1])
            self._banks_revision = board.revision
        return self._banks

    def pulls_in_every_switch(self) -> bool:
        """Whether the present drive pulls in every row and column switch (the bench can then
        take the commanded pixel for the lit one when it skips the switch dynamics)."""
        rows_bank, cols_bank = self.switch_banks()
        hv = self.board.supply().hv_v
        return bool(hv >= rows_bank.pull_in_v.max() and hv >= cols_bank.pull_in_v.max())

    def candidate_rows(self) -> np.ndarray:
        """The rows that can pass light at all: bonded ones, and any row switch stuck on (an
        unbonded row has no drive, but stuck on it still passes light)."""
        extra = self.board.stuck.rows_ever_on()
        return np.asarray(sorted(set(self.board.bonded) | set(extra)), np.int64)

    def beams(self, t0: np.ndarray, t1: np.ndarray, dwell: np.ndarray | None = None):
        """(window, row, col, transmission) of every beam above the floor in each window
        (:func:`sim_devices.fpsa.beams.beams_in_windows`)."""
        rows_bank, cols_bank = self.switch_banks()
        return beams_in_windows(rows_bank, cols_bank, self.candidate_rows(), self.config.cols,
                                self.config.beam_floor, t0, t1, dwell)

    def lit_beams(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, mean path transmission) of beams leaving the chip during [t0, t1]."""
        _, r, c, tr = self.beams(np.array([t0_s], float), np.array([t1_s], float))
        return r, c, tr

    def triggers(self, pattern: np.ndarray, sched: PixelSchedule, first: int, count: int,
                 capture_s: float) -> TriggerBatch:
        """Triggers ``first .. first+count-1`` of the run of ``pattern`` on ``sched`` and their lit beams.

        Pure computation from the schedule and the drive log: does not advance the clock.
        """
        total = sched.total_triggers
        if first < 0 or count < 0 or first + count > total:
            raise ValueError(
                f"fpga: triggers {first}..{first + count - 1} outside the run's 0..{total - 1}")
        if not capture_s >= 0 or not math.isfinite(capture_s):
            raise ValueError(f"fpga: capture_s must be finite and >= 0, got {capture_s!r}")
        if count == 0:
            return TriggerBatch.empty(capture_s)
        # the triggers of a run are a function of the run and the drive log: a block of at least
        # TRIGGERS_AHEAD is computed at once and the next reads are cut from it (the fixed cost of a
        # call, ~40 numpy calls, once per block instead of per read), until the log changes
        key = (sched, self.board.revision, float(capture_s))
        ahead = self._ahead
        if ahead is None or ahead[0] != key or ahead[1] is not pattern \
                or not ahead[2] <= first <= first + count <= ahead[2] + len(ahead[3]):
            block = self._triggers(pattern, sched, first, min(total - first, max(count, TRIGGERS_AHEAD)), capture_s)
            ahead = self._ahead = (key, pattern, first, block)
        return ahead[3].window(first - ahead[2], first - ahead[2] + count)

    def _triggers(self, pattern: np.ndarray, sched: PixelSchedule, first: int, count: int,
                  capture_s: float) -> TriggerBatch:
        index = np.arange(first, first + count, dtype=np.int64)
        t = sched.trigger_s(index)
        pixel = (index // sched.triggers_per_pixel).astype(np.int32)
        px = pattern[pixel]
        bk, br, bc, bt = self.beams(t, t + capture_s, dwell=pixel)
        return TriggerBatch(
            index=index, t_s=t, pixel_index=pixel, row=px[:, 0].astype(np.int16),
            col=px[:, 1].astype(np.int16), beam_trigger=bk.astype(np.int32),
            beam_row=br.astype(np.int16), beam_col=bc.astype(np.int16),
            beam_transmission=bt.astype(np.float64), capture_s=float(capture_s))
