"""The FPGA simulator's drive log stays bounded over a long life (a daemon's child bench runs for
weeks), and forgetting old history changes nothing: a simulator that compacts its log at every START
and one that never does (settling horizon infinite) give bit-identical beams for every window of every
run, with the hold drive and a discharge RC (release delays), runs cut short by STOP, single pixels
set between runs and gaps both shorter and longer than the horizon."""

from __future__ import annotations

import math

import numpy as np

from drivers.fpsa import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from sim_devices.fpsa.drive_log import DriveEvents, compact, settle_horizon_s
from sim_devices.fpsa.hv_drive import HvDrive
from sim_devices.world.mems import SwitchDynamics

US = 1e-6


def _sim(horizon_s: float | None) -> tuple[VirtualClock, FpgaSim]:
    dyn = SwitchDynamics(0.9 * US, 1.3 * US, 32.0, 29.0, discharge_rc_s=0.4 * US)
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(rows=20, cols=20, bonded_rows=tuple(range(20)), row_dynamics=dyn,
                                    col_dynamics=dyn, threshold_spread_v=0.5, seed=3))
    sim.supply = lambda: HvDrive(35.0, hold_v=30.5)     # pull in at 35 V, hold at 30.5 V
    if horizon_s is not None:
        sim.board.settle_horizon_s = horizon_s
    _send(sim, p.Cmd.RESET)
    clock.advance(100 * US)
    return clock, sim


def _send(sim, cmd, payload=b""):
    r = p.decode_response(p.decode_frame(sim.feed(p.encode_frame(1, cmd, payload))))
    assert r.ok, r


def _start(sim, pixels: np.ndarray, settle_ns: int, period_ns: int) -> None:
    data = p.pack_pixels(pixels)
    _send(sim, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(len(pixels), p.crc32(data)))
    _send(sim, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, data))
    _send(sim, p.Cmd.PATTERN_END)
    _send(sim, p.Cmd.SET_TIMING, p.Timing(settle_ns=settle_ns, dwell_ns=0, triggers_per_pixel=1,
                                          trigger_period_ns=period_ns).pack())
    _send(sim, p.Cmd.ARM)
    _send(sim, p.Cmd.START)


def _life(horizon_s: float | None, runs: int = 40):
    """The same programme on a fresh simulator; answers the beams of every window and the log size."""
    rng = np.random.default_rng(7)
    clock, sim = _sim(horizon_s)
    seen = []
    for k in range(runs):
        pixels = rng.integers(0, 20, size=(int(rng.integers(3, 12)), 2))
        settle_ns, period_ns = int(rng.choice([500, 2_000, 20_000])), 4_000
        _start(sim, pixels, settle_ns, period_ns)
        t0 = clock.now()
        pix_s = (settle_ns + period_ns) * 1e-9
        n_win = len(pixels) if k % 5 else len(pixels) // 2          # every 5th run is cut short
        for i in range(n_win):
            a = t0 + i * pix_s
            seen.append(sim.lit_beams(a, a + pix_s))
            seen.append(sim.lit_beams(a + 0.3 * pix_s, a + 0.3 * pix_s))   # one instant, mid-settle
        clock.advance(n_win * pix_s)
        if k % 5 == 0:
            _send(sim, p.Cmd.STOP)
        # gaps shorter and much longer than the settling horizon (about 13 ms here)
        clock.advance(float(rng.choice([2 * US, 40 * US, 1e-3, 30e-3])))
        if k % 7 == 3:                                            # a pixel held between runs
            _send(sim, p.Cmd.SET_PIXEL, p.encode_set_pixel(int(rng.integers(0, 20)), int(rng.integers(0, 20))))
            clock.advance(float(rng.choice([3 * US, 50e-3])))
            a = clock.now()
            seen.append(sim.lit_beams(a, a + 5 * US))
            _send(sim, p.Cmd.CLEAR)
            clock.advance(5 * US)
    return seen, sim.drive_events()[0].size


def test_compaction_changes_no_beam_and_keeps_the_log_bounded():
    compacted, n_compacted = _life(None)
    whole, n_whole = _life(math.inf)
    assert len(compacted) == len(whole) > 200
    lit = 0
    for (r1, c1, t1), (r2, c2, t2) in zip(compacted, whole):
        assert np.array_equal(r1, r2) and np.array_equal(c1, c2)
        assert np.array_equal(t1, t2)                 # bit for bit, not approximately
        lit += r1.size
    assert lit > 100                                  # the windows did see light
    # the log: all of history without compaction, a few events per line and the last runs with it
    assert n_whole > 800 and n_compacted < n_whole / 3, (n_compacted, n_whole)


def test_a_bench_life_of_many_runs_keeps_few_events():
    clock, sim = _sim(None)
    horizon = settle_horizon_s(sim.config.row_dynamics, sim.config.col_dynamics)
    sizes = []
    for k in range(120):
        _start(sim, np.array([[k % 20, (3 * k) % 20], [(k + 1) % 20, k % 20]]), 2_000, 4_000)
        clock.advance(2 * horizon)
        sizes.append(sim.drive_events()[0].size)
    # 40 lines at most one old switch-off each, plus the newest run's own events
    assert max(sizes[10:]) <= 40 + 8 and max(sizes[60:]) <= max(sizes[10:60])


def test_compact_keeps_a_stuck_switchs_history_and_the_holds_after_the_cut():
    ev, holds = DriveEvents(), DriveEvents()
    for t in (0.0, 1.0, 2.0, 3.0):
        ev.add(0, [4, 5], t, 40.0)
        holds.add(0, [4, 5], t + 0.1, 30.0)
        ev.add(0, [4, 5], t + 0.5, 0.0)
    dropped = compact(ev, holds, 2.6, exempt={(0, 5)})
    kinds, lines, ts, vs = ev.arrays()
    # line 4: from its switch-off at 2.5 on; line 5 (stuck at some time): everything
    assert dropped == 5
    assert sorted(ts[lines == 4].tolist()) == [2.5, 3.0, 3.5]
    assert ts[lines == 5].size == 8
    hk, hl, ht, hv = holds.arrays()
    assert sorted(ht[hl == 4].tolist()) == [3.1] and ht[hl == 5].size == 4
