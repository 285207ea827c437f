"""The FPSA board's drive log: which HV line was driven to what voltage when, and the switches
that ignore it (§4.3.3; §4.2.6; faults of ``sim_devices.faults``).

The FPGA simulator never keeps "the current array state": it appends every HV583 line change to an
event log (:class:`DriveEvents`, a whole run's changes in closed form at START), and the MEMS
switch banks of ``sim_devices.world.mems`` are built from that log on demand. This module holds
the log and the views on it the simulator needs:

* :func:`lines_high_before`: which lines were driven high just before a moment;
* :func:`with_holds`: one line kind's drive events plus the hold-level events of the pull-in/hold
  drive (``sim_devices.fpsa.hv_drive``) that a later line change did not cut short;
* :class:`StuckSwitches`: fault injection, switches that ignore their drive during intervals, and
  the drive events such a switch actually follows (:func:`line_kind` checks a switch's name);
* :func:`compact`: the log of a bench that runs for weeks stays bounded. A line's history before its
  last switch-off that lies a settling horizon (:func:`settle_horizon_s`) in the past no longer
  shapes anything later: the off event is decisive (hysteresis target "off" whatever came before),
  and any difference in the level or in the release delay that the dropped events made has decayed
  below the last bit of a float64 by the horizon (it shrinks as exp(-t/tau) through every later
  event). Switches for whom the drive is decisive only by history (a stuck switch) are left whole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from sim_devices.fpsa.hv_drive import valid_holds

ROW, COL = 0, 1  # line kinds in the drive-event log

#: The settling horizon in units of the slowest time constant of a switch (response or discharge):
#: exp(-37) is below a float64 level's last bit, exp(-745) underflows; 1e4 leaves room for the
#: release delay of a discharge (a few RC) as well.
SETTLED_TIME_CONSTANTS = 1.0e4


@dataclass
class DriveEvents:
    """Append-only log of HV line drive changes: (kind, line, t_s, volts)."""

    kind: list[np.ndarray] = field(default_factory=list)
    line: list[np.ndarray] = field(default_factory=list)
    t: list[np.ndarray] = field(default_factory=list)
    v: list[np.ndarray] = field(default_factory=list)

    def add(self, kind, line, t, v) -> None:
        line = np.atleast_1d(np.asarray(line, np.int64))
        n = line.size
        self.kind.append(np.broadcast_to(np.asarray(kind, np.int8), (n,)).copy())
        self.line.append(line)
        self.t.append(np.broadcast_to(np.asarray(t, np.float64), (n,)).copy())
        self.v.append(np.broadcast_to(np.asarray(v, np.float64), (n,)).copy())

    def arrays(self):
        if not self.kind:
            z = np.zeros(0)
            return z.astype(np.int8), z.astype(np.int64), z, z
        return (np.concatenate(self.kind), np.concatenate(self.line), np.concatenate(self.t),
                np.concatenate(self.v))


def settle_horizon_s(*dynamics) -> float:
    """How long before a moment a switch-off must lie for the history before it to be forgotten."""
    return SETTLED_TIME_CONSTANTS * max(max(d.tau_on_s, d.tau_off_s, d.discharge_rc_s) for d in dynamics)


def compact(events: DriveEvents, holds: DriveEvents, t_cut_s: float, exempt=frozenset()) -> int:
    """Drop, per line, the drive events (and hold events) before its last switch-off at or before
    ``t_cut_s`` (see the module notes); ``exempt`` (kind, line) pairs keep their whole history. The
    log becomes one slot, in the order the events were logged. Returns the number of events dropped."""
    kinds, lines, ts, vs = events.arrays()
    if kinds.size == 0:
        return 0
    key = kinds.astype(np.int64) * (1 << 32) + lines
    order = np.lexsort((np.arange(key.size), ts, key))        # per line, in time, then logged order
    k_o, t_o, v_o = key[order], ts[order], vs[order]
    off = np.flatnonzero((v_o == 0.0) & (t_o <= t_cut_s))
    if off.size == 0:
        return 0
    # the last such switch-off of each line, and where that line's run of events starts
    last_off = off[np.r_[k_o[off][1:] != k_o[off][:-1], True]]
    start = np.searchsorted(k_o, k_o[last_off], side="left")
    drop_o = np.zeros(key.size, bool)
    cut_at: dict[int, float] = {}
    for s, e in zip(start.tolist(), last_off.tolist()):
        k = int(k_o[e])
        if (k >> 32, k & 0xFFFFFFFF) in exempt or e == s:
            continue
        drop_o[s:e] = True
        cut_at[k] = float(t_o[e])
    n_drop = int(drop_o.sum())
    if n_drop == 0:
        return 0
    keep = np.ones(key.size, bool)
    keep[order[drop_o]] = False
    events.kind, events.line, events.t, events.v = [kinds[keep]], [lines[keep]], [ts[keep]], [vs[keep]]
    hk, hl, ht, hv = holds.arrays()
    if hk.size:
        hkey = hk.astype(np.int64) * (1 << 32) + hl
        cut = np.array([cut_at.get(int(k), -math.inf) for k in hkey.tolist()])
        hkeep = ht >= cut                    # a hold before the line's switch-off applied before it
        holds.kind, holds.line, holds.t, holds.v = [hk[hkeep]], [hl[hkeep]], [ht[hkeep]], [hv[hkeep]]
    return n_drop


def lines_high_before(events: DriveEvents, rows: int, cols: int,
                      t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column lines (bool per line) driven high by the events strictly before ``t_s``."""
    kinds, lines, ts, vs = events.arrays()
    out = []
    for k, n in ((ROW, rows), (COL, cols)):
        high = np.zeros(n, bool)
        m = (kinds == k) & (ts < t_s)
        order = np.argsort(ts[m], kind="stable")
        high[lines[m][order]] = vs[m][order] > 0  # later events overwrite earlier ones
        out.append(high)
    return out[0], out[1]


def with_holds(kind: int, kinds, lines, ts, vs, holds: DriveEvents):
    """Drive events of one line kind, with the hold-level events that still apply."""
    m = kinds == kind
    ln, t, v = lines[m], ts[m], vs[m]
    hk, hl, ht, hv = holds.arrays()
    hm = hk == kind
    keep = valid_holds(ln, t, v, hl[hm], ht[hm])
    if not keep.any():
        return ln, t, v
    return (np.concatenate([ln, hl[hm][keep]]), np.concatenate([t, ht[hm][keep]]),
            np.concatenate([v, hv[hm][keep]]))


def line_kind(line: str, index: int, rows: int, cols: int) -> int:
    """ROW or COL for a switch named ``line`` ('row' | 'col') and ``index``, or a ValueError naming
    the bad one."""
    if line not in ("row", "col"):
        raise ValueError(f"fpga: switch line must be 'row' or 'col', got {line!r}")
    n = rows if line == "row" else cols
    if not (isinstance(index, (int, np.integer)) and 0 <= index < n):
        raise ValueError(f"fpga: {line} index must be 0..{n - 1}, got {index!r}")
    return ROW if line == "row" else COL


class StuckSwitches:
    """Switches that ignore their drive: (kind, line) -> [[t_from, t_to, on], ...] intervals.

    Not thread-safe on its own: the FPGA simulator calls it under its lock.
    """

    def __init__(self) -> None:
        self._intervals: dict[tuple[int, int], list[list]] = {}

    def stick(self, kind: int, index: int, on: bool, t_s: float) -> None:
        """From ``t_s`` the switch stays on/off (re-sticking ends the previous interval)."""
        intervals = self._intervals.setdefault((kind, index), [])
        if intervals and math.isinf(intervals[-1][1]):
            intervals[-1][1] = t_s
        intervals.append([t_s, math.inf, bool(on)])

    def release(self, kind: int, index: int, t_s: float) -> None:
        """From ``t_s`` the switch follows its drive again."""
        for iv in self._intervals.get((kind, index), []):
            if math.isinf(iv[1]):
                iv[1] = max(t_s, iv[0])

    def lines(self) -> frozenset[tuple[int, int]]:
        """(kind, line) of every switch that is or was stuck (its history matters: never compacted)."""
        return frozenset(self._intervals)

    def stuck_now(self) -> list[tuple[str, int, bool]]:
        """(line, index, on) of the switches stuck right now (an interval without end)."""
        return [("row" if k == ROW else "col", line, iv[-1][2])
                for (k, line), iv in self._intervals.items() if iv and math.isinf(iv[-1][1])]

    def rows_ever_on(self) -> list[int]:
        """Rows that are (or were) stuck on at some time: they may pass light without drive."""
        return [line for (k, line), ivs in self._intervals.items()
                if k == ROW and any(on for _, _, on in ivs)]

    def apply(self, kind: int, lines: np.ndarray, ts: np.ndarray, vs: np.ndarray):
        """The drive events a switch actually follows: inside a stuck interval [t0, t1) its own
        events are ignored and it is held on (infinite drive) or off (0 V); at t1 it picks up the
        drive the HV583 holds at that moment."""
        extra_l, extra_t, extra_v = [], [], []
        keep = np.ones(lines.size, bool)
        for (k, line), intervals in self._intervals.items():
            if k != kind:
                continue
            mine = lines == line
            for t0, t1, on in intervals:
                keep &= ~(mine & (ts >= t0) & (ts < t1))
                extra_l.append(line)
                extra_t.append(t0)
                extra_v.append(math.inf if on else 0.0)
                if math.isfinite(t1):
                    before = np.flatnonzero(mine & (ts < t1))
                    drive = 0.0
                    if before.size:
                        last = before[np.argsort(ts[before], kind="stable")[-1]]
                        drive = float(vs[last])
                    extra_l.append(line)
                    extra_t.append(t1)
                    extra_v.append(drive)
        if not extra_l:
            return lines, ts, vs
        # the added events go first: at equal times SwitchBank keeps the given order, so the
        # stuck/release event precedes any drive event logged for the same instant
        return (np.concatenate([np.asarray(extra_l, np.int64), lines[keep]]),
                np.concatenate([np.asarray(extra_t, np.float64), ts[keep]]),
                np.concatenate([np.asarray(extra_v, np.float64), vs[keep]]))
