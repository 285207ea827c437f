"""Serial faults on the FPGA's pty: byte drops and bit flips (the FPSA driver's CRC / NAK / retry
copes and nothing uploaded is corrupted) and disconnect / reconnect behind the stable symlink."""

import os

import numpy as np
import pytest
import serial

from drivers.fpsa import protocol as fp_p
from drivers.transport import DeviceTimeout
from drivers.transport.errors import TransportError
from tests.helpers.deadlines import REPLY_S
from tests.helpers.sim_bench import fpsa

PATTERN = np.array([[r, c] for r in range(0, 40) if r % 4 != 3 for c in range(0, 40, 3)])


def _exercise(fp, n: int) -> None:
    """n round trips of different sizes: status (short) and identify (long answer)."""
    for k in range(n):
        if k % 2:
            assert fp.identify().rows == 128
        else:
            assert fp.status().state in tuple(fp_p.State)


def test_bit_flips_are_caught_by_crc_and_retried_then_clearing_stops_them(bench):
    bench.inject_fault("serial_flip", rate=0.005)
    # small chunks: at a byte error rate p a frame of L bytes gets through with (1 - p)^L
    fp = fpsa(bench, timeout_s=0.05, retries=12, backoff_s=0.0, chunk_pixels=32)
    fp.reset()
    _exercise(fp, 60)
    fp.upload_pattern(PATTERN)               # ~1 kB of frames through the noisy line
    assert bench.serial_line.bytes_flipped > 5
    assert fp.retry_count > 0                 # NAK BAD_CRC / garbled answers were retried
    # nothing corrupt got through: the FPGA holds exactly the pattern (PATTERN_END checked its CRC)
    assert np.array_equal(bench.fpga.firmware.pattern.astype(np.int64), PATTERN)
    fp.close()
    bench.clear_faults("serial_flip")
    _clean_line_after_clearing(bench)


def _clean_line_after_clearing(bench) -> None:
    """After the fault is cleared the line is clean: a driver that may not retry at all (and waits for
    every answer as long as a loaded machine may need) gets every answer, and no byte is touched."""
    flipped, dropped = bench.serial_line.bytes_flipped, bench.serial_line.bytes_dropped
    strict = fpsa(bench, timeout_s=REPLY_S, retries=0, backoff_s=0.0)
    _exercise(strict, 40)
    assert strict.retry_count == 0
    assert (bench.serial_line.bytes_flipped, bench.serial_line.bytes_dropped) == (flipped, dropped)
    strict.close()


def test_byte_drops_time_out_and_are_retried_then_clearing_stops_them(bench):
    bench.inject_fault("serial_drop", rate=0.01)
    fp = fpsa(bench, timeout_s=0.05, retries=12, backoff_s=0.0)
    executed = bench.fpga.executed
    _exercise(fp, 60)
    assert bench.serial_line.bytes_dropped > 5 and fp.retry_count > 0
    # a retry re-sends the same seq: a command whose ACK was lost is answered from the FPGA's
    # cache, never executed twice, so executions <= commands
    assert bench.fpga.executed - executed <= 60
    fp.close()
    bench.clear_faults("serial_drop")
    _clean_line_after_clearing(bench)


def test_disconnect_removes_the_device_and_reconnect_reuses_the_stable_path(bench):
    url = bench.endpoints()["fpsa_url"]
    assert os.path.islink(url) and os.path.realpath(url).startswith("/dev/pts/")
    fp = fpsa(bench, timeout_s=0.05, retries=1, backoff_s=0.0)
    fp.reset()
    run_before = fp.status()
    bench.inject_fault("serial_disconnect")
    assert not os.path.lexists(url)          # the device node vanished
    with pytest.raises((TransportError, DeviceTimeout, serial.SerialException, OSError)):
        fp.status()
    with pytest.raises(TransportError):
        fpsa(bench)                          # nothing to open
    assert bench.clear_faults("serial_disconnect") == 1
    assert os.path.islink(url) and os.path.realpath(url).startswith("/dev/pts/")
    assert bench.endpoints()["fpsa_url"] == url   # the published path is stable
    fresh = fpsa(bench, timeout_s=REPLY_S)
    assert fresh.identify().model == "FPSA128-HV583"
    # the board kept its state through the cable pull: still IDLE after the earlier RESET
    assert fresh.status().state == run_before.state == fp_p.State.IDLE
    fresh.close()
    fp.close()


def test_disconnect_with_reconnect_after_comes_back_on_the_virtual_clock(bench):
    url = bench.endpoints()["fpsa_url"]
    bench.inject_fault("serial_disconnect", reconnect_after_s=0.25)
    bench.clock.advance(0.2)
    assert not os.path.lexists(url)
    assert [f["kind"] for f in bench.active_faults()] == ["serial_disconnect"]
    bench.clock.advance(0.1)
    assert os.path.islink(url) and bench.active_faults() == []
    fp = fpsa(bench)
    assert fp.identify().cols == 128
    fp.close()
