"""The vectorised MEMS switch evaluation (one searchsorted over switch-major event keys, windows x
switches in one pass) against a straightforward reference written here event by event in plain
Python: pull-in/release hysteresis of §4.2.6, first-order relaxation with the ON/OFF response times
of §4.3.6, and the FPGA's beam selection with stuck switches (the ``stuck_switch`` fault) on seeded
random patterns."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.fpsa import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from sim_devices.world.mems import COLUMN_SWITCH, ROW_SWITCH, SwitchBank, mean_path_transmission


def _reference_events(n, dyn, sw, t, v, init):
    """Per switch: list of (t, target_on, level_at_t, tau) after hysteresis, in time order
    (ties in the given order), starting with a settled pseudo-event at -inf."""
    out = []
    for s in range(n):
        mine = sorted((float(t[i]), i, float(v[i])) for i in range(len(sw)) if sw[i] == s)
        state = bool(init[s])
        level = 1.0 if state else 0.0
        evs = [(-math.inf, state, level, dyn.tau_on_s if state else dyn.tau_off_s)]
        for te, _, ve in mine:
            _, prev_on, prev_level, prev_tau = evs[-1]
            # relax from the previous event to this one
            a = 1.0 if prev_on else 0.0
            level = a + (prev_level - a) * math.exp(-(te - evs[-1][0]) / prev_tau) \
                if math.isfinite(evs[-1][0]) else prev_level
            if ve >= dyn.pull_in_v:
                state = True
            elif ve <= dyn.release_v:
                state = False
            evs.append((te, state, level, dyn.tau_on_s if state else dyn.tau_off_s))
        out.append(evs)
    return out


def _ref_last(evs, tq):
    k = 0
    for i, e in enumerate(evs):
        if e[0] <= tq:
            k = i
    return k


def _ref_transmission(evs, tq):
    te, on, level, tau = evs[_ref_last(evs, tq)]
    a = 1.0 if on else 0.0
    if not math.isfinite(te):
        return level
    return a + (level - a) * math.exp(-(tq - te) / tau)


def _ref_possibly_lit(evs, t0, t1, floor):
    if _ref_transmission(evs, t0) > floor or _ref_transmission(evs, t1) > floor:
        return True
    return any(t0 < e[0] <= t1 and e[1] for e in evs)


def _random_bank(rng, n, dyn, n_events, t_span):
    sw = rng.integers(0, n, n_events)
    # coarse time grid so that ties (several events at one instant) occur
    t = np.round(rng.uniform(0.0, t_span, n_events) / 0.25e-6) * 0.25e-6
    v = rng.choice([0.0, 10.0, 30.0, 31.0, 40.0, math.inf], n_events)
    init = rng.random(n) < 0.3
    return sw, t, v, init


@pytest.mark.parametrize("seed", range(6))
def test_transmission_and_lit_windows_match_the_event_by_event_reference(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 7))
    dyn = COLUMN_SWITCH if seed % 2 else ROW_SWITCH
    sw, t, v, init = _random_bank(rng, n, dyn, int(rng.integers(0, 40)), 20e-6)
    bank = SwitchBank(n, dyn, sw, t, v, init)
    ref = _reference_events(n, dyn, sw, t, v, init)

    # query times on and around event times (ties with events are the delicate case)
    tq = np.concatenate([rng.uniform(-2e-6, 24e-6, 60), t, np.nextafter(t, -np.inf)])
    sq = rng.integers(0, n, tq.size)
    got = bank.transmission(sq, tq)
    want = np.array([_ref_transmission(ref[s], q) for s, q in zip(sq, tq)])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    on = bank.is_on(sq, tq)
    np.testing.assert_array_equal(on, [ref[s][_ref_last(ref[s], q)][1] for s, q in zip(sq, tq)])

    t0 = np.sort(rng.uniform(-2e-6, 22e-6, 25))
    t1 = t0 + rng.choice([0.0, 0.5e-6, 3e-6], t0.size)
    floor = 1e-3
    switches = np.arange(n)[rng.permutation(n)]
    lit = bank.possibly_lit_many(switches, t0, t1, floor)
    assert lit.shape == (t0.size, n)
    want_lit = np.array([[_ref_possibly_lit(ref[s], a, b, floor) for s in switches]
                         for a, b in zip(t0, t1)], dtype=bool)
    np.testing.assert_array_equal(lit, want_lit)
    for j, s in enumerate(switches):  # the single-switch form agrees with the batched one
        np.testing.assert_array_equal(bank.possibly_lit(int(s), t0, t1, floor), lit[:, j])


def test_last_event_matches_a_per_switch_searchsorted():
    rng = np.random.default_rng(42)
    n = 17
    sw, t, v, init = _random_bank(rng, n, COLUMN_SWITCH, 500, 50e-6)
    bank = SwitchBank(n, COLUMN_SWITCH, sw, t, v, init)
    tq = np.concatenate([rng.uniform(-5e-6, 55e-6, 2000), t, [-np.inf, np.inf]])
    sq = rng.integers(0, n, tq.size)
    got = bank._last_event(sq, tq)
    # the old per-switch loop, kept here as the reference
    want = np.empty_like(got)
    for s in range(n):
        m = sq == s
        lo, hi = bank._start[s], bank._stop[s]
        want[m] = lo + np.searchsorted(bank._t[lo:hi], tq[m], side="right") - 1
    np.testing.assert_array_equal(got, want)
    assert np.all(bank._sw[got] == sq)
    assert np.all(bank._t[got] <= tq)


def test_possibly_lit_many_names_a_bad_switch():
    bank = SwitchBank(4, ROW_SWITCH, [0], [1e-6], [40.0])
    with pytest.raises(ValueError, match="0..3"):
        bank.possibly_lit_many(np.array([0, 4]), np.zeros(2), np.ones(2), 1e-3)
    with pytest.raises(ValueError, match="same length"):
        bank.possibly_lit_many(np.array([0]), np.zeros(2), np.ones(3), 1e-3)


# --- FPGA beams (row-column paths) with stuck switches ----------------------------------------
def _send(sim, seq, cmd, payload=b""):
    r = p.decode_response(p.decode_frame(sim.feed(p.encode_frame(seq, cmd, payload))))
    assert r.ok, r


def _reference_beams(sim, t0, t1):
    """Every (window, row, col) path above the floor, by looping over windows and switches."""
    rows_bank, cols_bank = sim.optics.switch_banks()
    floor = sim.config.beam_floor
    cand_rows = sim.optics.candidate_rows()
    out = []
    for k in range(t0.size):
        a, b = t0[k:k + 1], t1[k:k + 1]
        lit_r = [int(r) for r in cand_rows if rows_bank.possibly_lit(int(r), a, b, floor)[0]]
        lit_c = [c for c in range(sim.config.cols) if cols_bank.possibly_lit(c, a, b, floor)[0]]
        for r in lit_r:
            for c in lit_c:
                tr = float(mean_path_transmission(rows_bank, np.array([r]), cols_bank,
                                                  np.array([c]), a, b)[0])
                if tr > floor:
                    out.append((k, r, c, tr))
    return sorted(out)


@pytest.mark.parametrize("seed", range(3))
def test_fpga_beams_with_stuck_switches_match_the_loop_reference(seed):
    rng = np.random.default_rng(100 + seed)
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig())
    rows = np.asarray(sim.board.bonded)
    pattern = np.stack([rng.choice(rows, 24), rng.integers(0, sim.config.cols, 24)], 1)
    px = p.pack_pixels(pattern)
    _send(sim, 1, p.Cmd.RESET)
    clock.advance(100e-6)
    _send(sim, 2, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(len(pattern), p.crc32(px)))
    _send(sim, 3, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px))
    _send(sim, 4, p.Cmd.PATTERN_END)
    # settle well past the 2.7 us response so a healthy window sees exactly one beam
    tm = p.Timing(settle_ns=20000, dwell_ns=1000, triggers_per_pixel=2, trigger_period_ns=3000)
    _send(sim, 5, p.Cmd.SET_TIMING, tm.pack())
    _send(sim, 6, p.Cmd.ARM)
    _send(sim, 7, p.Cmd.START)
    start = sim.run_start_s
    # a column stuck on for part of the run, a bonded row stuck off, an unbonded row stuck on
    unbonded = sorted(set(range(sim.config.rows)) - set(sim.board.bonded))
    sim.stick_switch("col", int(pattern[3, 1]), True, t_s=start + 50e-6)
    sim.release_switch("col", int(pattern[3, 1]), t_s=start + 300e-6)
    sim.stick_switch("row", int(pattern[10, 0]), False, t_s=start + 100e-6)
    if unbonded:
        sim.stick_switch("row", int(unbonded[seed % len(unbonded)]), True, t_s=start + 500e-6)

    # triggers() finds candidate switches once per pixel dwell (2 triggers here), exact per trigger
    b = sim.triggers(0, sim.total_triggers, 1.5e-6)
    assert np.all(np.diff(b.beam_trigger) >= 0)           # window-major, as the synthesis expects
    got = sorted(zip(b.beam_trigger.tolist(), b.beam_row.tolist(), b.beam_col.tolist(),
                     b.beam_transmission.tolist()))
    want = _reference_beams(sim, b.t_s, b.t_s + 1.5e-6)
    assert [g[:3] for g in got] == [w[:3] for w in want]
    np.testing.assert_allclose([g[3] for g in got], [w[3] for w in want], rtol=1e-12, atol=0)
    # the faults show: some window sees two beams (stuck-on column), some sees none
    per_window = np.bincount(b.beam_trigger, minlength=b.t_s.size)
    assert per_window.max() >= 2 and per_window.min() == 0
    healthy = b.t_s + 1.5e-6 < start + 50e-6  # windows that end before the first fault
    assert healthy.sum() >= 2 and np.all(per_window[healthy] == 1)


@pytest.mark.parametrize("seed", range(4))
def test_the_floor_test_skips_the_exponential_only_where_it_cannot_change_the_answer(seed):
    """possibly_lit_many decides settled switches without the time, and skips switches dark over a
    group of windows; the answers equal the full evaluation a + b > floor at every (switch, window
    end), also for floors at the levels themselves (a level at an event, one ulp above or below it)."""
    rng = np.random.default_rng(100 + seed)
    n = 9
    dyn = ROW_SWITCH if seed % 2 else COLUMN_SWITCH
    sw, t, v, init = _random_bank(rng, n, dyn, 60, 20e-6)
    bank = SwitchBank(n, dyn, sw, t, v, init)
    tw = np.sort(np.concatenate([rng.uniform(-2e-6, 24e-6, 40), t]))
    idx = bank._last_event(np.repeat(np.arange(n), tw.size), np.tile(tw, n))
    levels = bank._level[np.isfinite(bank._level) & (bank._level > 0) & (bank._level < 1)]
    floors = [0.0, 1e-3, 0.5, 1.0, *levels[:3], *np.nextafter(levels[:3], 2.0), *np.nextafter(levels[:3], -1.0)]
    tq = np.tile(tw, n)
    for floor in floors:
        a, b, _ = bank._state(idx, tq)
        np.testing.assert_array_equal(bank._above(idx, tq, float(floor)), a + b > floor)

    # the whole test, dark groups skipped, against the full evaluation of every (switch, window)
    t0 = tw[:-1]
    t1 = t0 + rng.choice([0.0, 0.2e-6, 2e-6], t0.size)
    for floor in floors:
        got = bank.possibly_lit_many(np.arange(n), t0, t1, float(floor))
        i0 = bank._last_event(np.repeat(np.arange(n), t0.size), np.tile(t0, n))
        i1 = bank._last_event(np.repeat(np.arange(n), t1.size), np.tile(t1, n))
        a0, b0, _ = bank._state(i0, np.tile(t0, n))
        a1, b1, _ = bank._state(i1, np.tile(t1, n))
        full = (a0 + b0 > floor) | (a1 + b1 > floor) | (bank._cum_on[i1] - bank._cum_on[i0] > 0)
        np.testing.assert_array_equal(got, full.reshape(n, t0.size).T)


@pytest.mark.parametrize("seed", range(4))
def test_switches_dark_over_a_group_of_windows_are_skipped_with_the_same_answers(seed):
    """A slow drive (events ~40 us apart, switches settle in ~20 us): many (switch, group) pairs are
    dark and skipped; possibly_lit_many still answers what the full evaluation does."""
    rng = np.random.default_rng(200 + seed)
    n = 12
    dyn = ROW_SWITCH if seed % 2 else COLUMN_SWITCH
    sw, t, v, init = _random_bank(rng, n, dyn, 40, 1.6e-3)
    bank = SwitchBank(n, dyn, sw, t, v, init)
    t0 = np.sort(rng.uniform(-0.1e-3, 1.7e-3, 400))
    t1 = t0 + rng.choice([0.0, 1e-6, 20e-6], t0.size)
    switches = rng.permutation(n)
    floor = 1e-3
    live = bank._live_queries(switches.astype(np.int64), t0, t1, floor)
    assert 0 < live.size < 0.8 * n * t0.size                      # the shortcut is taken, not everywhere
    got = bank.possibly_lit_many(switches, t0, t1, floor)
    ref = _reference_events(n, dyn, sw, t, v, init)
    want = np.array([[_ref_possibly_lit(ref[s], a, b, floor) for s in switches] for a, b in zip(t0, t1)], bool)
    np.testing.assert_array_equal(got, want)
