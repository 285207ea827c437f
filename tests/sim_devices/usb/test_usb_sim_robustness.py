"""Simulator side of the codecs: golden segment bytes produced by SimDigitizer, and the simulated
devices' reaction to arbitrary host bytes (only pyusb USB errors, never a crash)."""

import errno

import numpy as np
import usb.core
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.awg import protocol as awgp
from drivers.awg.driver import AwgDriver
from drivers.digitizer import protocol as dp
from drivers.digitizer.driver import DigitizerDriver
from drivers.usbtmc import DeviceDisconnected
from sim_devices.awg.device import SimAwg
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import RemoteUsbBackend, SimUsbBackend, UsbBridgeServer

D4 = bytes.fromhex("44 47 53 47 01 10 01 00 05 00 00 00 02 00 00 00"
                   "E8 03 00 00 00 00 00 00 C7 9B C5 3E 72 41 12 F3"
                   "01 00 FE FF")


class GoldenSource:
    """Segment k has samples [1, -2] and triggers at k * 0.2 us (segment 5 -> 1 us, as in D4)."""

    def capture(self, first, count, cfg):
        codes = np.tile(np.array([[1, -2]], np.int16), (count, 1, 1))
        return CapturedSegments(np.arange(first, first + count) * 0.2e-6, codes,
                                np.zeros((count, 1), bool))


def test_sim_digitizer_emits_golden_segment_bytes():
    sim = SimDigitizer(VirtualClock(), GoldenSource())
    dev = usb.core.find(idVendor=dp.DIGITIZER_VID, idProduct=dp.DIGITIZER_PID,
                        backend=SimUsbBackend([sim]))
    dev.ctrl_transfer(0x40, 0x10, 0x01, 0, None)
    dev.ctrl_transfer(0x40, 0x12, 0, 0, dp.enc_u32(2))
    dev.ctrl_transfer(0x40, 0x13, 0, 0, dp.enc_u32(6))
    dev.ctrl_transfer(0x40, 0x14, 16, 0, None)
    dev.ctrl_transfer(0x40, 0x20, 0, 0, None)
    dev.ctrl_transfer(0x40, 0x40, 0, 0, bytes.fromhex("05 00 00 00 01 00 00 00"))
    assert bytes(dev.read(0x81, 4096)) == D4


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.binary(max_size=64), max_size=6))
def test_sim_awg_survives_arbitrary_bulk_out(transfers):
    sim = SimAwg()
    for t in transfers:
        assert sim.usb_bulk_out(0x01, memoryview(t)) == len(t)
    try:
        sim.usb_bulk_in(0x82, memoryview(bytearray(1024)))
    except usb.core.USBError:
        pass
    assert len(sim.errors) <= 32


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 255), st.integers(0, 0xFFFF), st.binary(max_size=16), st.booleans())
def test_sim_digitizer_refuses_bad_requests_with_stall_only(req, w_value, data, dir_in):
    sim = SimDigitizer(VirtualClock(), GoldenSource())
    bm = 0xC0 if dir_in else 0x40
    try:
        sim.usb_ctrl(bm, req, w_value, 0, None if dir_in else data, 64)
    except usb.core.USBError as exc:
        assert exc.errno == errno.EPIPE


def test_bench_process_gone_is_a_disconnect():
    awg = SimAwg()
    server = UsbBridgeServer([awg])
    backend = RemoteUsbBackend(f"tcp://127.0.0.1:{server.port}")
    dev = usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend)
    drv = AwgDriver(dev, timeout_ms=100, retries=1)
    assert drv.identify().model == "AWG-16"
    server.close()
    try:
        drv.output(True)
        raise AssertionError("expected DeviceDisconnected")
    except DeviceDisconnected as exc:
        assert exc.device == "awg"
    finally:
        backend.close()


def test_digitizer_driver_over_bridge_reads_golden_samples():
    sim = SimDigitizer(VirtualClock(), GoldenSource())
    server = UsbBridgeServer([sim])
    backend = RemoteUsbBackend(server.url)
    try:
        dev = usb.core.find(idVendor=dp.DIGITIZER_VID, idProduct=dp.DIGITIZER_PID, backend=backend)
        drv = DigitizerDriver(dev)
        drv.configure(channels=("beat",), sample_rate_hz=1e6, record_length=2, segments=6)
        drv.arm()
        (h,), s = drv.read_segments(5, 1)
        assert h.trigger_time_ns == 1000 and h.payload_crc32 == 0x3EC59BC7
        assert s.tolist() == [[[1, -2]]]
    finally:
        backend.close()
        server.close()


def test_bridge_keeps_nothing_of_finished_connections():
    """A bench serves daemon after daemon: each finished connection's socket and thread are dropped
    (a list of them grew by one per daemon session before)."""
    awg = SimAwg()
    server = UsbBridgeServer([awg])
    try:
        for _ in range(8):
            backend = RemoteUsbBackend(server.url)
            dev = usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend)
            assert AwgDriver(dev, timeout_ms=500, retries=1).identify().model == "AWG-16"
            backend.close()
        threads = list(server._threads)
        for t in threads:
            t.join(timeout=10)
        assert not any(t.is_alive() for t in threads)
        assert server._threads == [] and server._conns == []
    finally:
        server.close()
