"""Simulated FPGA: golden vectors on the device side, HV583 model, state machine, wire time."""

from __future__ import annotations

import os
import re
import struct
from pathlib import Path

import numpy as np
import pytest

from drivers.fpsa import protocol as p
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import HV583, FpgaConfig, FpgaSim, default_bonded_rows

DOC = Path(__file__).resolve().parents[3] / "docs" / "protocols" / "fpsa.md"


def golden() -> dict[str, bytes]:
    block = re.search(r"```golden\n(.*?)```", DOC.read_text(), re.S).group(1)
    return {f[0].strip(): bytes.fromhex(f[4].strip())
            for f in (line.split("|") for line in block.strip().splitlines())}


G = golden()


def send(sim: FpgaSim, seq: int, cmd: int, payload: bytes = b"") -> p.Response:
    return p.decode_response(p.decode_frame(sim.feed(p.encode_frame(seq, cmd, payload))))


def reset_sim(**cfg) -> tuple[VirtualClock, FpgaSim]:
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(**cfg))
    assert send(sim, 200, p.Cmd.RESET).ok
    return clock, sim


def test_golden_vectors_device_side():
    sim = FpgaSim(VirtualClock())
    assert sim.feed(G["reset_req"]) == G["reset_ack"]
    assert sim.feed(G["set_pixel_req"]) == G["set_pixel_ack"]
    rows, cols = sim.lines_high(sim.clock.now() + 1e-6)
    assert np.flatnonzero(rows).tolist() == [5] and np.flatnonzero(cols).tolist() == [64]
    ack = p.decode_response(p.decode_frame(sim.feed(G["pattern_begin4_req"])))
    assert ack.ok and ack.seq == 6
    assert sim.feed(G["pattern_chunk_unbonded_req"]) == G["nak_unbonded"]
    st = p.decode_response(p.decode_frame(sim.feed(G["status_req"])))
    assert st.seq == 0 and p.Status.unpack(st.data).state == p.State.IDLE
    ok = send(sim, 30, p.Cmd.PATTERN_BEGIN, bytes.fromhex("02 00 d2 1a 35 48"))
    assert ok.ok
    assert p.decode_response(p.decode_frame(sim.feed(G["pattern_chunk_req"]))).ok
    assert send(sim, 31, p.Cmd.PATTERN_END).ok  # (0,0) (1,5) checks against the golden CRC
    assert p.decode_response(p.decode_frame(sim.feed(G["set_timing_req"]))).ok
    assert sim.timing == p.Timing(8000, 0, 1, 80_000)


def test_hv583_shift_register_model_and_refresh_rate():
    hv = HV583(np.random.default_rng(1))
    want = np.zeros(128, bool)
    want[[0, 31, 32, 77, 127]] = True
    clocks = hv.shift_in(want)
    assert not np.array_equal(hv.outputs, want)  # the latch still holds the old data
    hv.latch_enable()
    np.testing.assert_array_equal(hv.outputs, want)
    assert clocks == 32
    # §4.3.3: 32-bit registers at 40 MHz -> full refresh 0.8 us, i.e. 1.25 MHz
    assert HV583.refresh_s() == pytest.approx(0.8e-6)
    assert 1 / HV583.refresh_s() == pytest.approx(1.25e6)
    # the first bit clocked in ends at the far end of the register
    hv2 = HV583(np.random.default_rng(2))
    hv2.clock_in([True, False, False, False])
    for _ in range(31):
        hv2.clock_in([False] * 4)
    hv2.latch_enable()
    assert np.flatnonzero(hv2.outputs).tolist() == [31]
    hv2.polarity_inverted = True
    assert hv2.outputs.sum() == 127
    hv2.blank = True
    assert not hv2.outputs.any()


def test_bonded_rows_default_skips_one_in_four():
    b = default_bonded_rows(128)
    assert len(b) == 96 and 3 not in b and 127 not in b and 126 in b


def test_power_up_garbage_until_reset_then_cleared():
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(seed=11))
    rows, cols = sim.lines_high()
    assert rows.sum() > 1 and cols.sum() > 1  # random latches, outputs live
    assert not rows[[r for r in range(128) if r % 4 == 3]].any()  # unbonded rows go nowhere
    r, c, t = sim.lit_beams(clock.now() + 20e-6, clock.now() + 30e-6)
    assert r.size == rows.sum() * cols.sum()  # every lit row x every lit column: ghost grid
    st = sim.status()
    assert st.state == p.State.FAULT
    assert st.faults & p.FaultFlag.HV_UNINITIALIZED and st.faults & p.FaultFlag.MULTI_ROW
    assert send(sim, 1, p.Cmd.SET_PIXEL, p.encode_set_pixel(0, 0)).code == p.NakCode.BAD_STATE
    assert send(sim, 2, p.Cmd.IDENTIFY).ok
    assert send(sim, 3, p.Cmd.RESET).ok
    rows, cols = sim.lines_high(clock.now() + 1e-6)
    assert not rows.any() and not cols.any()
    for hv in (sim.hv_rows, sim.hv_cols):
        assert not hv.latch.any() and not hv.shift.any()
    # light dies away with the switch-off dynamics: nothing above the floor 30 us later
    r, c, t = sim.lit_beams(clock.now() + 30e-6, clock.now() + 40e-6)
    assert r.size == 0
    st = sim.status()
    assert st.state == p.State.IDLE and st.faults == p.FaultFlag.NONE


def test_each_transaction_advances_clock_by_wire_time():
    clock, sim = reset_sim(baudrate=1_000_000)
    t0 = clock.now()
    req = p.encode_frame(9, p.Cmd.STATUS)
    resp = sim.feed(req)
    assert clock.now() - t0 == pytest.approx((len(req) + len(resp)) * 10 / 1e6)
    assert len(req) == 8 and len(resp) == 22


def test_retry_with_same_seq_is_answered_from_cache_not_re_executed():
    clock, sim = reset_sim()
    px = p.pack_pixels(np.array([[0, 0], [1, 1]]))
    assert send(sim, 1, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(2, p.crc32(px))).ok
    assert send(sim, 2, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px)).ok
    assert send(sim, 3, p.Cmd.PATTERN_END).ok
    assert send(sim, 4, p.Cmd.ARM).ok
    start = p.encode_frame(5, p.Cmd.START)
    first = sim.feed(start)
    n = sim.executed
    run_start = sim.run_start_s
    assert sim.feed(start) == first  # same bytes back
    assert sim.executed == n and sim.run_start_s == run_start  # not restarted
    # a new seq with the same command does execute (and is refused: already running)
    assert send(sim, 6, p.Cmd.START).code == p.NakCode.BAD_STATE


def test_bad_crc_is_nakked_and_not_executed():
    clock, sim = reset_sim()
    inner = bytearray(p.encode_inner(8, p.Cmd.SET_PIXEL, p.encode_set_pixel(0, 1)))
    inner[-2] ^= 0xFF
    resp = p.decode_response(p.decode_frame(sim.feed(p.cobs_encode(bytes(inner)) + b"\x00")))
    assert (resp.ok, resp.code, resp.seq) == (False, p.NakCode.BAD_CRC, 8)
    rows, cols = sim.lines_high(clock.now() + 1e-6)
    assert not rows.any() and not cols.any()
    assert sim.status().faults & p.FaultFlag.LINK_ERRORS
    assert not sim.status().faults & p.FaultFlag.LINK_ERRORS  # cleared by reading
    # garbage without a seq is dropped silently, then the next frame is served
    assert sim.feed(b"\x05\x01\x00") == b""
    assert send(sim, 9, p.Cmd.IDENTIFY).ok


def test_pattern_upload_checks():
    clock, sim = reset_sim()
    px = p.pack_pixels(np.array([[0, 0], [1, 1], [2, 2]]))
    assert send(sim, 1, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(3, p.crc32(px) ^ 1)).ok
    assert send(sim, 2, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px[:4])).ok
    r = send(sim, 3, p.Cmd.PATTERN_END)
    assert (r.code, r.detail) == (p.NakCode.PATTERN_INCOMPLETE, 2)
    assert sim.status().faults & p.FaultFlag.PATTERN_INVALID
    assert send(sim, 4, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(2, px[4:])).ok
    assert send(sim, 5, p.Cmd.PATTERN_END).code == p.NakCode.PATTERN_CRC
    assert send(sim, 6, p.Cmd.ARM).code == p.NakCode.BAD_STATE  # nothing verified
    assert send(sim, 7, p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(3, p.crc32(px))).ok
    bad_chunk = bytearray(p.encode_pattern_chunk(0, px))
    bad_chunk[6] ^= 1  # first pixel byte changed after the chunk CRC was computed
    assert send(sim, 8, p.Cmd.PATTERN_CHUNK, bytes(bad_chunk)).code == p.NakCode.CHUNK_CRC
    beyond = send(sim, 9, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(2, px))
    assert beyond.code == p.NakCode.OUT_OF_RANGE
    assert send(sim, 10, p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(0, px)).ok
    assert send(sim, 11, p.Cmd.PATTERN_END).ok
    assert send(sim, 12, p.Cmd.ARM).ok
    too_big = p.encode_pattern_begin(128 * 128 + 1, 0)
    assert send(sim, 13, p.Cmd.PATTERN_BEGIN, too_big).code == p.NakCode.OUT_OF_RANGE


def test_nak_codes_for_malformed_commands():
    clock, sim = reset_sim()
    assert send(sim, 1, 0x55).code == p.NakCode.UNKNOWN_CMD
    assert send(sim, 2, p.Cmd.SET_PIXEL, b"\x01").code == p.NakCode.BAD_LENGTH
    assert send(sim, 3, p.Cmd.ARM, b"\x01").code == p.NakCode.BAD_LENGTH
    assert send(sim, 4, p.Cmd.SET_PIXEL, p.encode_set_pixel(0, 200)).code == p.NakCode.OUT_OF_RANGE
    bad_timing = p.Timing(8000, 0, 0, 1000).pack()
    assert send(sim, 5, p.Cmd.SET_TIMING, bad_timing).code == p.NakCode.BAD_TIMING
    short = p.Timing(8000, 0, 1, 50).pack()
    assert send(sim, 6, p.Cmd.SET_TIMING, short).code == p.NakCode.BAD_TIMING
    assert send(sim, 7, p.Cmd.START).code == p.NakCode.BAD_STATE
    assert send(sim, 8, p.Cmd.PATTERN_END).code == p.NakCode.BAD_STATE


def test_pty_server_serves_raw_bytes():
    clock = VirtualClock()
    sim = FpgaSim(clock)
    with sim.serve_pty() as srv:
        fd = os.open(srv.path, os.O_RDWR | os.O_NOCTTY)
        try:
            import tty

            tty.setraw(fd)
            os.write(fd, b"\x00garbage\x00" + G["reset_req"])
            got = b""
            while not got.endswith(b"\x00") or len(got) < len(G["reset_ack"]):
                got += os.read(fd, 64)
        finally:
            os.close(fd)
    assert got.endswith(G["reset_ack"])


def test_status_payload_layout_is_13_bytes():
    clock, sim = reset_sim()
    r = send(sim, 1, p.Cmd.STATUS)
    assert len(r.data) == 13
    state, faults, idx, pixels, trig = struct.unpack("<BHHII", r.data)
    assert (state, faults, idx, pixels, trig) == (0, 0, 0, 0, 0)
