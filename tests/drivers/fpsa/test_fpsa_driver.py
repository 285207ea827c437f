"""Driver <-> simulated FPGA round trips (in-memory pipe and a real pty), validation, retries."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.fpsa import protocol as p
from drivers.fpsa.driver import ChipLayout, FpsaController, FpsaLink, LinkError
from drivers.fpsa.errors import NakError, PatternError
from drivers.errors import DeviceGone, TransportError
from drivers.transport import DeviceTimeout
from sim_devices.clock import VirtualClock
from sim_devices.fpsa.device import FpgaConfig, FpgaSim
from tests.helpers.deadlines import REPLY_S

BONDED = tuple(r for r in range(128) if r % 4 != 3)


def make(chip: ChipLayout | None = None):
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(seed=3))
    sleeps: list[float] = []
    drv = FpsaController(sim.open_pipe(), link=FpsaLink(sleep=sleeps.append), chip=chip or ChipLayout())
    return clock, sim, drv, sleeps


def full_raster():
    rr, cc = np.meshgrid(np.array(BONDED), np.arange(128), indexing="ij")
    return np.stack([rr.ravel(), cc.ravel()], axis=1)


def exercise_every_command(drv: FpsaController, sim: FpgaSim, clock: VirtualClock) -> None:
    ident = drv.identify()
    assert (ident.rows, ident.cols) == (128, 128)
    assert ident.bonded_rows == BONDED and len(ident.bonded_rows) == 96
    assert drv.status().state == p.State.FAULT  # power-up garbage until RESET
    drv.reset()
    st = drv.status()
    assert st.state == p.State.IDLE and st.faults == p.FaultFlag.NONE
    drv.set_pixel(4, 77)
    rows_high, cols_high = sim.lines_high(clock.now() + 1e-6)
    assert np.flatnonzero(rows_high).tolist() == [4] and np.flatnonzero(cols_high).tolist() == [77]
    drv.clear()
    rows_high, cols_high = sim.lines_high(clock.now() + 1e-6)
    assert not rows_high.any() and not cols_high.any()
    pattern = np.array([[0, 0], [1, 2], [2, 4], [4, 6], [5, 8]])
    assert drv.upload_pattern(pattern) == 1
    tm = drv.set_timing(settle_ns=8000, dwell_ns=1000, triggers_per_pixel=3, trigger_period_ns=20_000)
    drv.arm()
    assert drv.status().state == p.State.ARMED
    drv.start()
    assert sim.total_triggers == 15
    period = 0.8e-6 + 8e-6 + 3 * 20e-6 + 1e-6
    st = drv.status()
    assert st.state == p.State.RUNNING and st.pattern_index == 0
    # the 8-byte STATUS request takes 8 * 10 / 3 Mbaud = 26.7 us on the wire before it executes
    clock.advance_to(sim.run_start_s + 2.5 * period - 8 * 10 / 3e6)
    st = drv.status()
    # 2.5 periods in: pixel 2 shown, its triggers at +8.8 us and +28.8 us (of 34.9 us) fired
    assert st.pattern_index == 2 and st.pixel_counter == 2 and st.trigger_counter == 8
    np.testing.assert_array_equal(sim.triggers(0, 15, 1e-6).row, np.repeat(pattern[:, 0], 3))
    drv.stop()
    st = drv.status()
    assert st.state == p.State.IDLE
    cut = sim.schedule.cut_s
    assert cut < clock.now()
    t_trig = (sim.run_start_s + np.arange(5)[:, None] * period + 8.8e-6
              + np.arange(3)[None, :] * 20e-6)
    assert 8 <= sim.total_triggers == int((t_trig < cut).sum()) < 15
    assert tm == p.Timing(8000, 1000, 3, 20_000)


def test_every_command_over_in_memory_pipe():
    clock, sim, drv, _ = make()
    exercise_every_command(drv, sim, clock)


def test_every_command_over_a_real_pty():
    clock = VirtualClock()
    sim = FpgaSim(clock, FpgaConfig(seed=3))
    with sim.serve_pty() as server:
        with FpsaController.from_url(server.path, link=FpsaLink(timeout_s=REPLY_S, retries=1)) as drv:
            exercise_every_command(drv, sim, clock)


def test_full_12288_pixel_pattern_over_pty_and_run_completes():
    clock = VirtualClock()
    sim = FpgaSim(clock)
    pattern = full_raster()
    with sim.serve_pty() as server, FpsaController.from_url(server.path, link=FpsaLink(timeout_s=REPLY_S)) as drv:
        drv.reset()
        assert drv.upload_pattern(pattern) == 12
        drv.set_timing(settle_ns=8000, trigger_period_ns=10_000)
        drv.arm()
        drv.start()
        clock.advance(12_288 * 20e-6)
        st = drv.status()
    assert st.state == p.State.DONE and st.pixel_counter == 12_288
    assert st.trigger_counter == 12_288 == sim.total_triggers


def test_driver_refuses_unbonded_and_out_of_range_before_sending():
    clock, sim, drv, _ = make(ChipLayout(rows=128, cols=128, bonded_rows=BONDED))
    sent_before = sim.rx_bytes
    bad = full_raster()
    bad[17] = (3, 9)  # row 3: one in four rows is not bonded (§4.3.3)
    with pytest.raises(PatternError) as ei:
        drv.upload_pattern(bad)
    assert ei.value.index == 17 and ei.value.row == 3
    assert "pixel 17" in str(ei.value) and "row 3" in str(ei.value)
    with pytest.raises(PatternError, match="pixel 1 .*column 128"):
        drv.upload_pattern(np.array([[0, 0], [0, 128]]))
    with pytest.raises(PatternError, match="row 200 outside"):
        drv.set_pixel(200, 0)
    with pytest.raises(PatternError, match="not wire-bonded"):
        drv.set_pixel(7, 0)
    with pytest.raises(PatternError, match="more than 16384"):
        drv.upload_pattern(np.zeros((16_385, 2), np.int64))
    with pytest.raises(PatternError, match="integers"):
        drv.upload_pattern(np.zeros((2, 2)))
    with pytest.raises(PatternError, match="empty"):
        drv.upload_pattern(np.zeros((0, 2), np.int64))
    assert sim.rx_bytes == sent_before  # nothing went on the wire


def test_fpga_naks_unbonded_row_when_driver_check_is_bypassed():
    clock, sim, drv, _ = make()
    drv.reset()
    # a driver that believes every row is bonded skips the local refusal
    liar = FpsaController(sim.open_pipe(), chip=ChipLayout(rows=128, cols=128, bonded_rows=range(128)))
    pattern = np.array([[0, 0], [1, 1], [2, 2], [3, 3]])
    with pytest.raises(NakError) as ei:
        liar.upload_pattern(pattern)
    assert ei.value.code == p.NakCode.BAD_ROW_UNBONDED and ei.value.nak_detail == 3
    assert ei.value.command == "PATTERN_CHUNK" and "fpsa" in str(ei.value)
    with pytest.raises(NakError) as ei:
        liar.set_pixel(7, 0)
    assert ei.value.code == p.NakCode.BAD_ROW_UNBONDED
    small = FpgaSim(VirtualClock(), FpgaConfig(rows=128, cols=100))
    liar2 = FpsaController(small.open_pipe(), chip=ChipLayout(rows=128, cols=128, bonded_rows=BONDED))
    liar2.reset()
    with pytest.raises(NakError) as ei:
        liar2.upload_pattern(np.array([[0, 0], [0, 99], [0, 100]]))
    assert ei.value.code == p.NakCode.OUT_OF_RANGE and ei.value.nak_detail == 2


class CorruptWrites:
    """Flips one byte of the first ``n`` frames written (line noise host -> FPGA)."""

    def __init__(self, inner, n=1):
        self.inner, self.n = inner, n

    def write(self, data):
        data = bytearray(data)
        if self.n and len(data) > 4:
            self.n -= 1
            data[-3] ^= 0x20  # inside the CRC bytes: still a well-formed COBS frame
        return self.inner.write(bytes(data))

    def __getattr__(self, name):
        return getattr(self.inner, name)


class DropAnswers:
    """Loses the FPGA's answer to the first ``n`` writes (they were executed, though)."""

    def __init__(self, inner, n=1):
        self.inner, self.n = inner, n
        self.timeout = None

    def write(self, data):
        r = self.inner.write(data)
        if self.n:
            self.n -= 1
            self.inner.reset_input_buffer()
        return r

    def read(self, size=1):
        return self.inner.read(size)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def test_crc_error_gets_nak_then_retry_succeeds():
    clock = VirtualClock()
    sim = FpgaSim(clock)
    sleeps = []
    drv = FpsaController(CorruptWrites(sim.open_pipe(), n=1), link=FpsaLink(sleep=sleeps.append, backoff_s=0.01))
    ident = drv.identify()
    assert ident.rows == 128
    assert drv.retry_count == 1 and sleeps == [0.01]
    assert sim.status().faults & p.FaultFlag.LINK_ERRORS  # the FPGA saw the bad frame


def test_lost_answer_is_retried_without_re_executing():
    clock = VirtualClock()
    sim = FpgaSim(clock)
    drv = FpsaController(sim.open_pipe(), link=FpsaLink(sleep=lambda s: None))
    drv.reset()
    drv.upload_pattern(np.array([[0, 0], [1, 1]]))
    drv.arm()
    lossy = FpsaController(DropAnswers(sim.open_pipe(), n=1), link=FpsaLink(sleep=lambda s: None))
    lossy._seq = 77  # a second host session with its own seq space
    executed = sim.executed
    lossy.start()  # first START executes, its ACK is lost; the retry gets the cached ACK
    assert sim.executed == executed + 1
    assert lossy.retry_count == 1
    assert sim.status().state in (p.State.RUNNING, p.State.DONE)


class DeadPort:
    def __init__(self):
        self.writes = []
        self.timeout = None

    def write(self, data):
        self.writes.append(bytes(data))
        return len(data)

    def read(self, size=1):
        return b""


def test_no_answer_bounded_retries_with_backoff_then_device_timeout():
    port = DeadPort()
    sleeps = []
    drv = FpsaController(port, link=FpsaLink(timeout_s=0.2, retries=3, backoff_s=0.05, sleep=sleeps.append))
    with pytest.raises(DeviceTimeout) as ei:
        drv.arm()
    err = ei.value
    assert err.device == "fpsa" and err.command == "ARM" and err.attempts == 4
    assert "fpsa" in str(err) and "ARM" in str(err)
    assert sleeps == [0.05, 0.1, 0.2]  # exponential backoff
    assert len(port.writes) == 4
    # the retries are the identical frame (same seq), after a lone flush byte
    assert port.writes[1] == b"\x00" + port.writes[0] == port.writes[2] == port.writes[3]
    assert port.timeout == 0.2


class GarbleAnswers:
    def __init__(self, inner):
        self.inner = inner

    def read(self, size=1):
        data = bytearray(self.inner.read(size))
        if len(data) > 3:
            data[-3] ^= 0x01
        return bytes(data)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def test_answers_always_garbled_gives_link_error():
    sim = FpgaSim(VirtualClock())
    drv = FpsaController(GarbleAnswers(sim.open_pipe()), link=FpsaLink(retries=2, sleep=lambda s: None))
    with pytest.raises(LinkError, match="IDENTIFY"):
        drv.identify()


def test_nak_bad_state_is_final_not_retried():
    clock, sim, drv, sleeps = make()
    with pytest.raises(NakError) as ei:
        drv.arm()  # still FAULT after power-up
    assert ei.value.code == p.NakCode.BAD_STATE and sleeps == []
    drv.reset()
    with pytest.raises(NakError) as ei:
        drv.arm()  # no verified pattern
    assert ei.value.code == p.NakCode.BAD_STATE
    with pytest.raises(ValueError):
        drv.set_timing(triggers_per_pixel=0)


def test_trace_logs_frames(caplog):
    import logging

    sim = FpgaSim(VirtualClock())
    drv = FpsaController(sim.open_pipe(), trace=True)
    with caplog.at_level(logging.DEBUG, logger="drivers.transport.wire"):
        drv.reset()
    msgs = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("fpsa TX") for m in msgs) and any(m.startswith("fpsa RX") for m in msgs)


def test_constructor_rejects_bad_arguments():
    with pytest.raises(TypeError):
        FpsaController(12345)
    with pytest.raises(ValueError):
        FpsaController(DeadPort(), link=FpsaLink(timeout_s=0))
    with pytest.raises(ValueError):
        FpsaController(DeadPort(), link=FpsaLink(retries=-1))


def test_channel_seam_reopen_and_from_url():
    # A port that fails once: the driver closes it and asks ``reopen`` for a fresh channel.
    sim = FpgaSim(VirtualClock())

    class Unplugged:
        timeout = None

        def write(self, data):
            raise OSError("device unplugged")

        def read(self, size=1):
            return b""

        def close(self):
            pass

    opened = []

    def reopen():
        opened.append(sim.open_pipe())
        return opened[-1]

    drv = FpsaController(Unplugged(), reopen=reopen, link=FpsaLink(sleep=lambda s: None))
    assert drv.identify().rows == 128
    assert drv.reconnect_count == 1 and len(opened) == 1 and opened[0].timeout == drv.timeout_s
    # without ``reopen`` a failed port is final, typed, and names device and command
    with pytest.raises(DeviceGone) as ei:
        FpsaController(Unplugged(), link=FpsaLink(sleep=lambda s: None)).status()
    assert (ei.value.device, ei.value.command) == ("fpsa", "STATUS")
    with pytest.raises(TransportError):
        FpsaController.from_url("nosuch://x")


def test_url_constructor_still_works_for_one_release():
    with pytest.warns(DeprecationWarning, match="from_url"):
        drv = FpsaController("loop://", link=FpsaLink(timeout_s=0.05, retries=0))
    assert drv.url == "loop://" and drv._reopen is not None
    drv.close()
