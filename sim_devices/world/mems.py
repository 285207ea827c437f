"""MEMS optical switch dynamics of the FPSA: electrostatic pull-in with hysteresis, and the
optical transmission of a row-column path versus time (§4.2.2, §4.2.6, §4.3.6).

Physics followed:

* Pull-in with hysteresis (§4.2.6, Fig. 4-15a): a parallel-plate actuator snaps down (switch ON)
  when its drive voltage reaches the pull-in voltage (32 V) and lets go (OFF) only when the
  voltage falls below the release voltage (29 V); in between it keeps its previous state.
* Response (§4.2.6, §4.3.6, Fig. 4-25): row switches respond in ~1 us; column switches of the
  128x128 FPSA in 2.7 us (ON) and 2.0 us (OFF). We model the optical transmission after a
  state change as a first-order relaxation ``T(t) = T_end + (T_0 - T_end) exp(-(t - t_cmd)/tau)``.
  **Response time is defined as command -> 90 % of the change** (the dissertation's wording,
  "the optical signal turns on or off within 1 us of the electrical signal", counts from the
  electrical edge), so ``tau = t_response / ln 10``. A switch commanded while still moving
  relaxes from wherever it is, so overlapping transitions are handled exactly.
* Spread across switches: the pull-in and release voltages of a real array scatter from switch to
  switch (gap and spring stiffness vary over the wafer). :func:`switch_thresholds` draws each
  switch's pair from a seeded normal spread of one common offset (the gap sets both thresholds,
  so they move together and the hysteresis width stays that of §4.2.6).
* Release delay (HV583 output discharge): when a line goes to 0 V the actuator's capacitance
  discharges through the HV583 output with time constant ``discharge_rc_s``; the plate lets go
  when the voltage crosses the release voltage, ``rc * ln(V_drive / V_release)`` after the command.
  Holding at a voltage just above release (the hold-drive option of the controller) therefore
  releases sooner than holding at the full actuation voltage, and charges the dielectric less.
* Row-column addressing (§4.2.1): light leaves through pixel (r, c) only when row switch r and
  column switch c are both on: path transmission = T_row(t) * T_col(t). Transmissions are
  normalised to 1 for a fully-on switch; insertion loss belongs to the optics model.

Everything is vectorised over many switches and many query times, and capture-window averages
are integrated in closed form (piecewise exponentials), so no time-stepping error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LN10 = math.log(10.0)  # 90 % of a first-order step is reached after tau * ln 10


@dataclass(frozen=True)
class SwitchDynamics:
    """Electro-mechanical parameters of one kind of MEMS switch."""

    on_response_s: float
    off_response_s: float
    pull_in_v: float = 32.0  # §4.2.6
    release_v: float = 29.0  # §4.2.6
    discharge_rc_s: float = 0.0  # HV583 output + actuator capacitance; 0 = instant discharge

    def __post_init__(self) -> None:
        if not (self.on_response_s > 0 and self.off_response_s > 0):
            raise ValueError(f"response times must be > 0 s, got {self!r}")
        if not (math.isfinite(self.discharge_rc_s) and self.discharge_rc_s >= 0):
            raise ValueError(f"discharge_rc_s must be finite and >= 0 s, got {self.discharge_rc_s!r}")
        if not self.release_v < self.pull_in_v:
            raise ValueError(
                f"release_v ({self.release_v}) must be below pull_in_v ({self.pull_in_v})")

    @property
    def tau_on_s(self) -> float:
        return self.on_response_s / LN10

    @property
    def tau_off_s(self) -> float:
        return self.off_response_s / LN10


ROW_SWITCH = SwitchDynamics(on_response_s=1.0e-6, off_response_s=1.0e-6)  # §4.3.6
COLUMN_SWITCH = SwitchDynamics(on_response_s=2.7e-6, off_response_s=2.0e-6)  # §4.3.6


def switch_thresholds(n: int, dynamics: SwitchDynamics, spread_v: float,
                      seed: int | list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Per-switch (pull_in_v, release_v) of ``n`` switches: nominal + one seeded N(0, spread_v)
    offset each (both thresholds move together). ``spread_v = 0`` gives the nominal values."""
    if not (math.isfinite(spread_v) and spread_v >= 0):
        raise ValueError(f"threshold spread must be finite and >= 0 V, got {spread_v!r}")
    offset = spread_v * np.random.default_rng(seed).standard_normal(n) if spread_v else np.zeros(n)
    return dynamics.pull_in_v + offset, dynamics.release_v + offset


def hysteresis_states(volts: np.ndarray, initial_on: np.ndarray | bool,
                      pull_in_v: float, release_v: float) -> np.ndarray:
    """Switch state after each drive-voltage sample along the last axis.

    ON once ``v >= pull_in_v``, OFF once ``v <= release_v``, otherwise unchanged (the state
    before the first sample is ``initial_on``). Vectorised: forward-fill of the last decisive
    sample.
    """
    v = np.asarray(volts, dtype=np.float64)
    on = v >= pull_in_v
    decisive = on | (v <= release_v)
    n = v.shape[-1]
    idx = np.where(decisive, np.arange(n), -1)
    last = np.maximum.accumulate(idx, axis=-1)
    init = np.broadcast_to(np.asarray(initial_on, dtype=bool)[..., None], v.shape)
    taken = np.take_along_axis(on, np.maximum(last, 0), axis=-1)
    return np.where(last >= 0, taken, init)


#: a level this far from the floor decides "above the floor" without evaluating its exponential
#: (SwitchBank._above); rounding moves a + b by ~1e-16
_DECIDED_MARGIN = 1e-9
#: a level within this of its target counts as settled there (SwitchBank._settled_s: ~21 time
#: constants after a full swing)
_SETTLED_TOL = 1e-9
#: windows per group in which a switch dark throughout is skipped (SwitchBank._live_queries): a
#: pixel's dwell spans, a few tens of them a group, see a few switches change
_GROUP_WINDOWS = 16


class SwitchBank:
    """Drive history and optical response of ``n`` switches of one kind.

    Built from drive events ``(switch, t_s, volts)``: at ``t_s`` the drive of ``switch``
    becomes ``volts`` (HV583 outputs are switched, so the drive is piecewise constant).
    Hysteresis turns each drive event into a target state; the transmission then relaxes toward
    it with the ON or OFF time constant. Events at identical times keep their given order.
    """

    def __init__(self, n: int, dynamics: SwitchDynamics, switch: np.ndarray, t_s: np.ndarray,
                 volts: np.ndarray, initial_on: np.ndarray | None = None,
                 thresholds: tuple[np.ndarray, np.ndarray] | None = None) -> None:
        sw = np.asarray(switch, dtype=np.int64).ravel()
        t = np.asarray(t_s, dtype=np.float64).ravel()
        v = np.asarray(volts, dtype=np.float64).ravel()
        if not (sw.shape == t.shape == v.shape):
            raise ValueError("switch, t_s and volts must have the same length")
        if sw.size and (sw.min() < 0 or sw.max() >= n):
            raise ValueError(f"switch index outside 0..{n - 1}")
        if not np.all(np.isfinite(t)):
            raise ValueError("event times must be finite")
        init = np.zeros(n, bool) if initial_on is None else np.asarray(initial_on, bool)
        self.n = n
        self.dynamics = dynamics
        # A pseudo-event at -inf per switch carries the initial state, so every query time has
        # a "last event" and the evaluation needs no special case.
        all_sw = np.concatenate([np.arange(n), sw])
        all_t = np.concatenate([np.full(n, -np.inf), t])
        all_v = np.concatenate([np.where(init, np.inf, -np.inf), v])
        order = np.lexsort((np.arange(all_sw.size), all_t, all_sw))
        self._sw, self._t, v_sorted = all_sw[order], all_t[order], all_v[order]
        counts = np.bincount(self._sw, minlength=n)
        self._stop = np.cumsum(counts)
        self._start = self._stop - counts
        pull, rel = (np.full(n, dynamics.pull_in_v), np.full(n, dynamics.release_v)) \
            if thresholds is None else (np.asarray(thresholds[0], float), np.asarray(thresholds[1], float))
        if pull.shape != (n,) or rel.shape != (n,) or np.any(rel >= pull):
            raise ValueError(f"thresholds must be two ({n},) arrays with release < pull-in")
        self.pull_in_v, self.release_v = pull, rel
        on = v_sorted >= pull[self._sw]
        decisive = on | (v_sorted <= rel[self._sw])  # pseudo-events are always decisive
        if dynamics.discharge_rc_s > 0:
            self._t = self._release_delayed(v_sorted, on, decisive, rel, dynamics.discharge_rc_s)
        last = np.maximum.accumulate(np.where(decisive, np.arange(on.size), -1))
        self._target = on[last].astype(np.float64)
        self._tau = np.where(self._target > 0.5, dynamics.tau_on_s, dynamics.tau_off_s)
        self._level = self._levels_at_events()
        self._cum_on = np.cumsum(self._target)
        # when each event's level is within _SETTLED_TOL of its target (-inf: already at the event);
        # the tolerance halved against the rounding of log and exp
        swing = np.abs(self._level - self._target)
        with np.errstate(divide="ignore"):
            self._settled_s = np.where(swing > _SETTLED_TOL / 2,
                                       self._t + self._tau * np.log(swing / (_SETTLED_TOL / 2)), -np.inf)
        # One sorted key per event, switch-major: key = switch * stride + rank of its time among
        # all event times. "Event e of switch s is at or before t" is then "key_e <= key(s, t)",
        # so the last event of any (switch, time) query is one searchsorted for the whole batch
        # instead of one per distinct switch (the per-switch loop cost ~30 ms per digitizer read).
        self._t_all = np.sort(self._t)
        self._stride = np.int64(self._t.size + 1)
        self._key = self._sw * self._stride + np.searchsorted(self._t_all, self._t, side="right")

    def _release_delayed(self, v: np.ndarray, on: np.ndarray, decisive: np.ndarray,
                         rel: np.ndarray, rc_s: float) -> np.ndarray:
        """Event times with each release moved to when the discharging drive crosses the
        switch's release voltage (never past the switch's next event, so the order holds)."""
        t = self._t.copy()
        prev_v = np.concatenate([[0.0], v[:-1]])
        same = np.concatenate([[False], self._sw[1:] == self._sw[:-1]])
        release = decisive & ~on & same & np.isfinite(prev_v) & (prev_v > rel[self._sw])
        idx = np.flatnonzero(release)
        if idx.size:
            delay = rc_s * np.log(prev_v[idx] / rel[self._sw[idx]])
            nxt = np.where((idx + 1 < t.size) & (self._sw[np.minimum(idx + 1, t.size - 1)]
                                                  == self._sw[idx]),
                           t[np.minimum(idx + 1, t.size - 1)], np.inf)
            t[idx] = np.minimum(t[idx] + delay, nxt)
        return t

    def _levels_at_events(self) -> np.ndarray:
        t, target, tau = self._t.tolist(), self._target.tolist(), self._tau.tolist()
        sw = self._sw.tolist()
        level = [0.0] * len(t)
        for k in range(len(t)):
            if k == 0 or sw[k] != sw[k - 1]:
                level[k] = target[k]  # pseudo-event: settled initial state
            else:
                a, tp = target[k - 1], tau[k - 1]
                level[k] = a + (level[k - 1] - a) * math.exp(-(t[k] - t[k - 1]) / tp)
        return np.asarray(level, dtype=np.float64)

    # --- evaluation --------------------------------------------------------------------------
    def _last_event(self, switch: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Index of the last event of ``switch[i]`` at or before ``t_s[i]``.

        The rank of a query time (number of event times <= it) orders exactly like the time
        itself against every event time, so the switch-major keys compare correctly.
        """
        switch = np.asarray(switch, dtype=np.int64)
        t_s = np.asarray(t_s, dtype=np.float64)
        rank = np.searchsorted(self._t_all, t_s, side="right")
        return np.searchsorted(self._key, switch * self._stride + rank, side="right") - 1

    def _next_event_time(self, idx: np.ndarray) -> np.ndarray:
        nxt = idx + 1
        ok = nxt < self._stop[self._sw[idx]]
        return np.where(ok, self._t[np.minimum(nxt, self._t.size - 1)], np.inf)

    def _state(self, idx: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(target A, offset B, tau) so that T(t') = A + B exp(-(t' - t_s)/tau) after t_s."""
        a = self._target[idx]
        tau = self._tau[idx]
        b = (self._level[idx] - a) * np.exp(-(t_s - self._t[idx]) / tau)
        return a, b, tau

    def transmission(self, switch: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Transmission (0..1) of ``switch[i]`` at ``t_s[i]`` (broadcast together)."""
        sw, t = np.broadcast_arrays(np.asarray(switch, np.int64), np.asarray(t_s, np.float64))
        idx = self._last_event(sw.ravel(), t.ravel())
        a, b, _ = self._state(idx, t.ravel())
        return (a + b).reshape(sw.shape)

    def is_on(self, switch: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        """Commanded (post-hysteresis) state of ``switch[i]`` at ``t_s[i]``."""
        sw, t = np.broadcast_arrays(np.asarray(switch, np.int64), np.asarray(t_s, np.float64))
        return self._target[self._last_event(sw.ravel(), t.ravel())].reshape(sw.shape) > 0.5

    def possibly_lit(self, switch: int, t0_s: np.ndarray, t1_s: np.ndarray,
                     floor: float) -> np.ndarray:
        """Whether ``switch`` may exceed ``floor`` anywhere in each window [t0, t1].

        Between events a level is monotone, so checking both ends and "any ON command inside"
        is a safe over-approximation used to pick candidate beams.
        """
        t0 = np.asarray(t0_s, np.float64)
        return self.possibly_lit_many(np.array([switch], np.int64), t0.ravel(),
                                      np.asarray(t1_s, np.float64).ravel(), floor).reshape(t0.shape)

    def possibly_lit_many(self, switches: np.ndarray, t0_s: np.ndarray, t1_s: np.ndarray,
                          floor: float) -> np.ndarray:
        """:meth:`possibly_lit` of every switch in ``switches`` (S,) for every window of the
        1-D ``t0_s``/``t1_s`` (W,), as a (W, S) array, in one vectorised pass."""
        sw1 = np.asarray(switches, np.int64).ravel()
        t0 = np.asarray(t0_s, np.float64).ravel()
        t1 = np.asarray(t1_s, np.float64).ravel()
        if t0.shape != t1.shape:
            raise ValueError(f"t0_s and t1_s must have the same length, got {t0.size} and {t1.size}")
        if sw1.size and (sw1.min() < 0 or sw1.max() >= self.n):
            raise ValueError(f"switch index outside 0..{self.n - 1}: {sw1.min()}..{sw1.max()}")
        # Switch-major (S, W) layout: the rank of a time is shared by all switches, and with the
        # windows in time order the query keys come sorted, which keeps searchsorted in cache.
        n_s, n_w = sw1.size, t0.size
        out = np.zeros(n_s * n_w, bool)
        if n_s == 0 or n_w == 0:
            return out.reshape(n_w, n_s) if n_s == 0 else out.reshape(n_s, n_w).T
        r0 = np.searchsorted(self._t_all, t0, side="right")
        r1 = np.searchsorted(self._t_all, t1, side="right")
        k = self._live_queries(sw1, t0, t1, floor)
        s_k, w_k = k // n_w, k % n_w
        i0 = np.searchsorted(self._key, sw1[s_k] * self._stride + r0[w_k], side="right") - 1
        i1 = np.searchsorted(self._key, sw1[s_k] * self._stride + r1[w_k], side="right") - 1
        on_inside = (self._cum_on[i1] - self._cum_on[i0]) > 0
        out[k] = self._above(i0, t0[w_k], floor) | self._above(i1, t1[w_k], floor) | on_inside
        return out.reshape(n_s, n_w).T

    def _live_queries(self, sw1: np.ndarray, t0: np.ndarray, t1: np.ndarray, floor: float) -> np.ndarray:
        """Switch-major indices (s * W + w) of the (switch, window) queries that need evaluating: all
        but those of a switch DARK over a group of ``_GROUP_WINDOWS`` consecutive windows -- no event
        inside the group's span and, at its start, an OFF target it has settled to (its level then
        stays within ``_SETTLED_TOL`` of 0, below the floor, and nothing turns it on: the query's
        answer is False exactly). A scan's drive turns a few rows and columns on in a group of
        windows: most of the bank's switches are dark there and cost one lookup per group."""
        n_s, n_w = sw1.size, t0.size
        if not 2 * _SETTLED_TOL < floor < 1.0 - 2 * _SETTLED_TOL:
            return np.arange(n_s * n_w)
        starts = np.arange(0, n_w, _GROUP_WINDOWS)
        g0, g1 = np.minimum.reduceat(t0, starts), np.maximum.reduceat(t1, starts)
        base = (sw1 * self._stride)[:, None]
        j0 = np.searchsorted(self._key, (base + np.searchsorted(self._t_all, g0, side="right")).ravel(), side="right") - 1
        j1 = np.searchsorted(self._key, (base + np.searchsorted(self._t_all, g1, side="right")).ravel(), side="right") - 1
        dark = (j0 == j1) & (self._target[j0] == 0.0) & (self._settled_s[j0] <= np.tile(g0, n_s))
        live = ~dark.reshape(n_s, starts.size)[:, np.arange(n_w) // _GROUP_WINDOWS]
        return np.flatnonzero(live.ravel())

    def _above(self, idx: np.ndarray, t_q: np.ndarray, floor: float) -> np.ndarray:
        """``a + b > floor`` of :meth:`_state` (idx, t_q), the exponential evaluated only where it can
        change the answer.

        After its last event a switch's level goes from the level at the event to the target a
        (b = (level - a) e, 0 <= e <= 1, falling with time): once the event is ``_settled_s`` old,
        |b| <= ``_SETTLED_TOL`` and the answer is the target's (a is 0 or 1, the floor farther than
        twice that from both); before, where the level at the event and the target are both above
        or both below the floor, so is a + b. Both decide by margins far above rounding, so the
        answers are the exact evaluation's; only a switch in a transition across the floor needs
        its exponential (a few of a bank's, where every switch of every window needed one)."""
        a, level = self._target[idx], self._level[idx]
        out = np.minimum(a, level) > floor + _DECIDED_MARGIN
        unsure = ~out & (np.maximum(a, level) >= floor - _DECIDED_MARGIN)
        if 2 * _SETTLED_TOL < floor < 1.0 - 2 * _SETTLED_TOL:
            settled = t_q >= self._settled_s[idx]
            out |= settled & (a > floor)
            unsure &= ~settled
        k = np.flatnonzero(unsure)
        if k.size:
            a_u, b_u, _ = self._state(idx[k], t_q[k])
            out[k] = a_u + b_u > floor
        return out


def mean_path_transmission(rows: SwitchBank, row: np.ndarray, cols: SwitchBank, col: np.ndarray,
                           t0_s: np.ndarray, t1_s: np.ndarray) -> np.ndarray:
    """Mean of T_row[row](t) * T_col[col](t) over [t0, t1] for each query (exact).

    The window is cut at every event of either switch; on each piece both transmissions are
    single exponentials and the product integrates in closed form. A zero-length window gives
    the instantaneous path transmission.
    """
    row, col, t0, t1 = np.broadcast_arrays(np.asarray(row, np.int64), np.asarray(col, np.int64),
                                           np.asarray(t0_s, np.float64),
                                           np.asarray(t1_s, np.float64))
    row, col, t0, t1 = row.ravel(), col.ravel(), t0.ravel(), t1.ravel()
    if np.any(t1 < t0):
        raise ValueError("capture window must have t1_s >= t0_s")
    width = t1 - t0
    total = np.zeros(t0.shape, np.float64)
    point = width == 0
    if np.any(point):
        total[point] = (rows.transmission(row[point], t0[point])
                        * cols.transmission(col[point], t0[point]))
    active = np.flatnonzero(~point)
    a = t0.copy()
    while active.size:
        r, c, ta, tb = row[active], col[active], a[active], t1[active]
        ir = rows._last_event(r, ta)
        ic = cols._last_event(c, ta)
        b = np.minimum(np.minimum(rows._next_event_time(ir), cols._next_event_time(ic)), tb)
        d = b - ta
        a1, b1, tau1 = rows._state(ir, ta)
        a2, b2, tau2 = cols._state(ic, ta)
        tau12 = tau1 * tau2 / (tau1 + tau2)
        total[active] += (a1 * a2 * d
                          + a1 * b2 * tau2 * -np.expm1(-d / tau2)
                          + a2 * b1 * tau1 * -np.expm1(-d / tau1)
                          + b1 * b2 * tau12 * -np.expm1(-d / tau12))
        a[active] = b
        active = active[b < tb]
    out = np.where(point, total, total / np.where(point, 1.0, width))
    return np.clip(out, 0.0, 1.0)
