"""The FPGA's pattern run as the bench sees it: trigger times, commanded pixels, and the optical
transmission of every beam in each capture window, checked against the switch dynamics of
§4.2.6 / §4.3.6 computed independently here."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from drivers.fpsa import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim

TAU_ROW = 1.0e-6 / math.log(10)  # 90 % in 1 us
TAU_COL_ON = 2.7e-6 / math.log(10)
TAU_COL_OFF = 2.0e-6 / math.log(10)
REFRESH = 32 / 40e6


def send(sim, seq, cmd, payload=b""):
    r = p.decode_response(p.decode_frame(sim.feed(p.encode_frame(seq, cmd, payload))))
    assert r.ok, r
    return r


def run(pattern, timing: p.Timing, **cfg):
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(**cfg))
    px = p.pack_pixels(np.asarray(pattern))
    send(sim, 1, p.Cmd.RESET)
    clock.advance(100e-6)  # let the reset transients die out
    send(sim, 2, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(len(pattern), p.crc32(px)))
    send(sim, 3, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px))
    send(sim, 4, p.Cmd.PATTERN_END)
    send(sim, 5, p.Cmd.SET_TIMING, timing.pack())
    send(sim, 6, p.Cmd.ARM)
    send(sim, 7, p.Cmd.START)
    return clock, sim


def mean(f, a, b):
    return quad(f, a, b, epsabs=1e-14, limit=200)[0] / (b - a)


def test_trigger_times_and_pixels_follow_the_schedule():
    pattern = [[0, 0], [1, 5], [2, 9], [4, 1]]
    tm = p.Timing(settle_ns=3000, dwell_ns=2000, triggers_per_pixel=3, trigger_period_ns=5000)
    clock, sim = run(pattern, tm)
    assert sim.total_triggers == 12
    b = sim.triggers(0, 12, 0.0)
    period = REFRESH + 3e-6 + 3 * 5e-6 + 2e-6
    i, k = np.divmod(np.arange(12), 3)
    want = sim.run_start_s + i * period + REFRESH + 3e-6 + k * 5e-6
    np.testing.assert_allclose(b.t_s, want, rtol=0, atol=1e-15)
    assert b.index.dtype == np.int64 and b.t_s.dtype == np.float64
    assert b.pixel_index.dtype == np.int32 and b.row.dtype == np.int16
    np.testing.assert_array_equal(b.pixel_index, i)
    np.testing.assert_array_equal(b.col, np.array(pattern)[i, 1])
    part = sim.triggers(5, 4, 0.0)
    np.testing.assert_array_equal(part.index, [5, 6, 7, 8])
    np.testing.assert_allclose(part.t_s, want[5:9], rtol=0, atol=1e-15)


def test_triggers_is_pure_and_validates_its_range():
    clock, sim = run([[0, 0], [1, 1]], p.Timing(8000, 0, 2, 1000))
    now = clock.now()
    sim.triggers(0, 4, 1e-6)
    assert clock.now() == now
    assert len(sim.triggers(4, 0, 1e-6)) == 0
    with pytest.raises(ValueError, match="outside"):
        sim.triggers(3, 2, 1e-6)
    with pytest.raises(ValueError):
        sim.triggers(0, 1, -1.0)
    with pytest.raises(ValueError, match="no run"):
        FpgaSim(VirtualClock()).triggers(0, 1, 0.0)


def test_short_settle_reduces_transmission_as_dynamics_predict_and_shows_ghosts():
    settle, trig_period, capture = 500e-9, 2000e-9, 1e-6
    tm = p.Timing(settle_ns=500, dwell_ns=0, triggers_per_pixel=1, trigger_period_ns=2000)
    clock, sim = run([[0, 0], [1, 5]], tm)
    b = sim.triggers(0, 2, capture)
    period = REFRESH + settle + trig_period
    x0 = settle  # window starts `settle` after the latch of pixel 1
    # new beam (1, 5): both switches start from fully off at the latch
    new = mean(lambda x: (1 - math.exp(-x / TAU_ROW)) * (1 - math.exp(-x / TAU_COL_ON)),
               x0, x0 + capture)
    # old row 0 / column 0 had been rising for one pixel period, then fall from there
    r0 = 1 - math.exp(-period / TAU_ROW)
    c0 = 1 - math.exp(-period / TAU_COL_ON)
    old = mean(lambda x: r0 * math.exp(-x / TAU_ROW) * c0 * math.exp(-x / TAU_COL_OFF),
               x0, x0 + capture)
    cross_10 = mean(lambda x: (1 - math.exp(-x / TAU_ROW)) * c0 * math.exp(-x / TAU_COL_OFF),
                    x0, x0 + capture)
    rows, cols, trans = b.beams_of(1)
    got = {(int(r), int(c)): t for r, c, t in zip(rows, cols, trans)}
    assert set(got) == {(0, 0), (0, 5), (1, 0), (1, 5)}
    assert got[(1, 5)] == pytest.approx(new, rel=1e-9)
    assert got[(0, 0)] == pytest.approx(old, rel=1e-9)
    assert got[(1, 0)] == pytest.approx(cross_10, rel=1e-9)
    assert 0.1 < got[(1, 5)] < 0.5  # far from the settled 1.0: captured before the switch settled
    # two rows lit at once -> two (here: four) beams; both rows appear
    assert {0, 1} <= set(rows.tolist())
    # the commanded pixel is reported as commanded, whatever is lit
    assert (b.row[1], b.col[1]) == (1, 5)


def test_longer_settle_monotonically_restores_transmission():
    values = []
    for settle_ns in (0, 500, 1000, 3000, 8000):
        tm = p.Timing(settle_ns=settle_ns, dwell_ns=0, triggers_per_pixel=1, trigger_period_ns=1000)
        _, sim = run([[0, 0], [1, 5]], tm)
        r, c, t = sim.triggers(1, 1, 0.0).beams_of(0)
        hit = t[(r == 1) & (c == 5)]
        values.append(float(hit[0]) if hit.size else 0.0)  # below the beam floor: not reported
        # instantaneous: exactly the product of the two first-order rises
        x = settle_ns * 1e-9
        assert values[-1] == pytest.approx(
            (1 - math.exp(-x / TAU_ROW)) * (1 - math.exp(-x / TAU_COL_ON)), abs=1e-12)
    assert values == sorted(values) and values[0] == 0.0


def test_default_timing_waits_for_at_least_99_percent():
    # a diagonal: row and column both change at every pixel (the worst case)
    pattern = [[r, r] for r in (0, 1, 2, 4, 5, 6, 8)]
    _, sim = run(pattern, p.DEFAULT_TIMING)
    b = sim.triggers(0, len(pattern), 0.0)  # instantaneous, at the trigger edge
    for i in range(len(pattern)):
        r, c, t = b.beams_of(i)
        main = t[(r == b.row[i]) & (c == b.col[i])]
        assert main.size == 1 and main[0] >= 0.99
        assert t[~((r == b.row[i]) & (c == b.col[i]))].sum() < 1e-3  # ghosts have died away
    # the capture window of a whole chirp averages even closer to 1
    assert sim.triggers(3, 1, 80e-6).beams_of(0)[2].max() > 0.999


def test_supply_below_pull_in_voltage_switches_nothing():
    # 30 V lies between release (29 V) and pull-in (32 V): an OFF switch stays OFF (§4.2.6)
    _, sim = run([[0, 0], [1, 1]], p.DEFAULT_TIMING, hv_supply_v=30.0)
    assert sim.triggers(0, 2, 10e-6).beam_row.size == 0
    _, sim = run([[0, 0], [1, 1]], p.DEFAULT_TIMING, hv_supply_v=33.0)
    assert sim.triggers(0, 2, 10e-6).beam_row.size >= 2


def test_stop_truncates_the_run_and_darkens_the_array():
    tm = p.Timing(settle_ns=8000, dwell_ns=0, triggers_per_pixel=1, trigger_period_ns=100_000)
    clock, sim = run([[0, 0], [1, 1], [2, 2], [4, 4]], tm)
    period = REFRESH + 8e-6 + 100e-6
    clock.advance_to(sim.run_start_s + 1.5 * period)
    send(sim, 8, p.Cmd.STOP)
    assert sim.total_triggers == 2
    with pytest.raises(ValueError):
        sim.triggers(2, 1, 0.0)
    rows, cols = sim.lines_high()
    assert not rows.any() and not cols.any()
    r, c, t = sim.lit_beams(clock.now() + 40e-6, clock.now() + 50e-6)
    assert r.size == 0


def test_a_digitizer_armed_before_several_runs_numbers_their_triggers_on():
    """Segments since an arm count every trigger the board fires after it, run after run (a stream's
    frames on one digitizer acquisition): segment n of the second run's first trigger, with that run's
    pixels and times; armed during a run, the digitizer counts that run from its start (the simulator's
    leniency); armed between runs, from the next run; an earlier run cannot be synthesized."""
    pattern = [[0, 0], [1, 5], [2, 9]]
    tm = p.Timing(settle_ns=3000, dwell_ns=2000, triggers_per_pixel=2, trigger_period_ns=5000)
    clock, sim = run(pattern, tm)
    first_start = sim.run_start_s
    armed = first_start - 1e-6                       # armed just before the first START
    clock.advance(1e-3)                              # the first run (6 triggers) ends
    assert sim.triggers_since(armed, 0, 6, 0.0).t_s[0] == pytest.approx(first_start + REFRESH + 3e-6)
    send(sim, 8, p.Cmd.STOP)
    second = [[4, 1], [5, 2]]
    px = p.pack_pixels(np.asarray(second))
    send(sim, 9, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(len(second), p.crc32(px)))
    send(sim, 10, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px))
    send(sim, 11, p.Cmd.PATTERN_END)
    send(sim, 12, p.Cmd.ARM)
    send(sim, 13, p.Cmd.START)
    b = sim.triggers_since(armed, 6, 4, 0.0)          # segments 6..9: the second run's 4 triggers
    period = REFRESH + 3e-6 + 2 * 5e-6 + 2e-6
    i, k = np.divmod(np.arange(4), 2)
    np.testing.assert_allclose(b.t_s, sim.run_start_s + i * period + REFRESH + 3e-6 + k * 5e-6, atol=1e-15)
    np.testing.assert_array_equal(np.c_[b.row, b.col], np.asarray(second)[i])
    # armed during the first run, after its first two triggers: still counted from its start
    during = first_start + REFRESH + 3e-6 + 5e-6 + 1e-7
    np.testing.assert_allclose(sim.triggers_since(during, 6, 1, 0.0).t_s, b.t_s[:1])
    # armed between the runs: segment 0 is the second run's first trigger
    between = first_start + 5e-4
    np.testing.assert_allclose(sim.triggers_since(between, 0, 4, 0.0).t_s, b.t_s)
    with pytest.raises(ValueError, match="earlier run"):
        sim.triggers_since(armed, 5, 1, 0.0)


def test_segments_since_an_arm_stay_numbered_over_more_runs_than_the_board_remembers():
    """A stream longer than the runs the board keeps (RETIRED_RUNS_KEPT): read run by run, as a stream
    does, the segments of the 80th run are still that run's triggers."""
    from sim_devices.fpsa.firmware import RETIRED_RUNS_KEPT

    tm = p.Timing(settle_ns=3000, dwell_ns=0, triggers_per_pixel=1, trigger_period_ns=5000)
    clock, sim = run([[0, 0], [1, 1]], tm)
    armed = sim.run_start_s - 1e-6
    runs = RETIRED_RUNS_KEPT + 16
    seq = 8
    for k in range(runs):
        row = 4 * (k % 30)                            # bonded rows (every 4th row from 3 on is not)
        if k:
            pattern = np.array([[row, 0], [row, 1]])
            px = p.pack_pixels(pattern)
            for cmd, payload in ((p.Cmd.STOP, b""), (p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(2, p.crc32(px))),
                                 (p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px)), (p.Cmd.PATTERN_END, b""),
                                 (p.Cmd.ARM, b""), (p.Cmd.START, b"")):
                send(sim, seq % 256, cmd, payload)
                seq += 1
        b = sim.triggers_since(armed, 2 * k, 2, 0.0)
        assert b.row.tolist() == ([row, row] if k else [0, 1])
        assert b.t_s[0] > sim.run_start_s
        clock.advance(1e-4)


def _fields(b):
    return (b.index, b.t_s, b.pixel_index, b.row, b.col, b.beam_trigger, b.beam_row, b.beam_col,
            b.beam_transmission)


def test_reads_cut_from_a_block_of_triggers_equal_each_read_computed_alone(monkeypatch):
    import sim_devices.fpsa.beams as beams
    pattern = [[r, c] for r in (0, 1, 2, 4) for c in range(0, 40, 3)]
    tm = p.Timing(settle_ns=700, dwell_ns=0, triggers_per_pixel=3, trigger_period_ns=2000)   # ghosts
    _, sim = run(pattern, tm)
    total = sim.total_triggers
    reads = [(0, 7), (7, 30), (37, 1), (38, 60), (5, 9), (98, total - 98)]   # a re-read goes back
    monkeypatch.setattr(beams, "TRIGGERS_AHEAD", 40)
    cut = [sim.triggers(a, n, 1e-6) for a, n in reads]
    monkeypatch.setattr(beams, "TRIGGERS_AHEAD", 0)       # every read computed on its own
    _, fresh = run(pattern, tm)
    alone = [fresh.triggers(a, n, 1e-6) for a, n in reads]
    assert sum(len(b.beam_row) for b in alone) > sum(len(b) for b in alone)    # ghost beams in the windows
    for x, y in zip(cut, alone):
        for fx, fy in zip(_fields(x), _fields(y)):
            assert fx.dtype == fy.dtype
            np.testing.assert_array_equal(fx, fy)


def test_a_switch_stuck_after_a_block_was_computed_shows_in_the_next_read(monkeypatch):
    import sim_devices.fpsa.beams as beams
    monkeypatch.setattr(beams, "TRIGGERS_AHEAD", 1000)
    tm = p.Timing(settle_ns=8000, dwell_ns=0, triggers_per_pixel=2, trigger_period_ns=2000)
    _, sim = run([[0, c] for c in range(20)], tm)
    assert 30 not in sim.triggers(0, 4, 1e-6).beam_col      # the block of 40 triggers is computed here
    sim.stick_switch("col", 30, True, t_s=0.0)      # column 30 on from the start: every pixel of row 0 emits it
    later = sim.triggers(4, 4, 1e-6)
    assert {2, 3, 30} <= set(later.beam_col.tolist()) and set(later.beam_trigger[later.beam_col == 30]) == {0, 1, 2, 3}
