"""The simulated pyusb backends: descriptors, enumeration, errors, URL table, bridge framing."""

import errno
import socket
import struct

import numpy as np
import pytest
import usb.core
import usb.util

from drivers.awg import protocol as awgp
from drivers.digitizer import protocol as dp
from sim_devices.awg.device import SimAwg
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import (
    RemoteUsbBackend,
    SimUsbBackend,
    UsbBridgeServer,
    backend_from_url,
)


class ZeroSource:
    def capture(self, first, count, cfg):
        n = len(cfg.channels)
        return CapturedSegments(np.arange(first, first + count) * 1e-3,
                                np.zeros((count, n, cfg.record_length), np.int16),
                                np.zeros((count, n), bool))


@pytest.fixture(params=["inproc", "bridge"])
def bus(request):
    devices = [SimAwg(), SimDigitizer(VirtualClock(), ZeroSource())]
    if request.param == "inproc":
        yield backend_from_url("sim-usb://inproc", devices), devices
        return
    server = UsbBridgeServer(devices)
    backend = backend_from_url(server.url)
    assert isinstance(backend, RemoteUsbBackend)
    yield backend, devices
    backend.close()
    server.close()


def test_enumeration_and_descriptors(bus):
    backend, _ = bus
    found = list(usb.core.find(find_all=True, backend=backend))
    assert sorted((d.idVendor, d.idProduct) for d in found) == [(0x1209, 0xA901), (0x1209, 0xA902)]
    awg = usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend)
    awg.set_configuration()
    intf = awg.get_active_configuration()[(0, 0)]
    assert (intf.bInterfaceClass, intf.bInterfaceSubClass, intf.bInterfaceProtocol) == (0xFE, 3, 1)
    eps = {e.bEndpointAddress: usb.util.endpoint_type(e.bmAttributes) for e in intf}
    assert eps == {0x01: usb.util.ENDPOINT_TYPE_BULK, 0x82: usb.util.ENDPOINT_TYPE_BULK}
    assert (awg.manufacturer, awg.product, awg.serial_number) == ("lidard-sim", "AWG-16", "SIM0001")
    dig = usb.core.find(idVendor=dp.DIGITIZER_VID, idProduct=dp.DIGITIZER_PID, backend=backend)
    assert [e.bEndpointAddress for e in dig[0][(0, 0)]] == [0x81]


def test_golden_bytes_decoded_by_sim_awg_through_backend(bus):
    backend, (awg_sim, _) = bus
    dev = usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend)
    dev.set_configuration()
    g1 = bytes.fromhex("01 01 FE 00 06 00 00 00 01 00 00 00 2A 49 44 4E 3F 0A 00 00")
    g2 = bytes.fromhex("02 02 FD 00 00 00 01 00 00 00 00 00")
    assert dev.write(0x01, g1) == len(g1)
    dev.write(0x01, g2)
    reply = bytes(dev.read(0x82, 4096))
    answer = b"lidard-sim,AWG-16,SIM0001,1.0\n"  # 30 bytes -> padded to 32
    assert reply[:12] == bytes.fromhex("02 02 FD 00 1E 00 00 00 01 00 00 00")
    assert reply[12:] == answer + b"\x00\x00"
    # G5: the golden upload command lands in the DAC memory
    g5 = b"SOUR:DATA:ARB " + bytes.fromhex("23 31 36 00 00 FF 7F 01 80") + b"\n"
    hdr = bytes.fromhex("01 03 FC 00") + struct.pack("<I", len(g5)) + bytes.fromhex("01 00 00 00")
    dev.write(0x01, hdr + g5 + b"\x00" * (-len(g5) % 4))
    assert awg_sim.codes.tolist() == [0, 32767, -32767]


def test_golden_control_payload_decoded_by_sim_digitizer(bus):
    backend, (_, dig_sim) = bus
    dev = usb.core.find(idVendor=dp.DIGITIZER_VID, idProduct=dp.DIGITIZER_PID, backend=backend)
    dev.set_configuration()
    dev.ctrl_transfer(0x40, 0x11, 0, 0, bytes.fromhex("80 B2 E6 0E 00 00 00 00"))
    assert dig_sim.config.sample_rate_hz == 250_000_000
    dev.ctrl_transfer(0x40, 0x10, 0x0E, 0, None)
    assert dig_sim.config.channels == ("beat_i", "beat_q", "mzi")


def test_fault_kinds_arrive_as_pyusb_exceptions(bus):
    backend, (awg_sim, _) = bus
    dev = usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend)
    dev.set_configuration()
    awg_sim.inject_fault("timeout", "bulk_out")
    with pytest.raises(usb.core.USBTimeoutError) as ei:
        dev.write(0x01, b"\x00" * 12)
    assert ei.value.errno == errno.ETIMEDOUT
    awg_sim.inject_fault("stall", "ctrl")
    with pytest.raises(usb.core.USBError) as ei:
        dev.ctrl_transfer(0xA1, 5, 0, 0, 1)
    assert ei.value.errno == errno.EPIPE and not isinstance(ei.value, usb.core.USBTimeoutError)
    awg_sim.inject_fault("disconnect")
    with pytest.raises(usb.core.USBError) as ei:
        dev.read(0x82, 64)
    assert ei.value.errno == errno.ENODEV
    # a disconnected device is gone from the bus
    assert usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend) is None
    awg_sim.reconnect()
    assert usb.core.find(idVendor=awgp.AWG_VID, idProduct=awgp.AWG_PID, backend=backend) is not None


def test_unknown_standard_and_vendor_requests_stall(bus):
    backend, _ = bus
    dev = usb.core.find(idVendor=dp.DIGITIZER_VID, idProduct=dp.DIGITIZER_PID, backend=backend)
    with pytest.raises(usb.core.USBError) as ei:
        dev.ctrl_transfer(0xC0, 0x7F, 0, 0, 4)
    assert ei.value.errno == errno.EPIPE


def test_backend_from_url_scheme_table():
    with pytest.raises(ValueError, match="unknown USB backend URL scheme"):
        backend_from_url("usb-magic://x")
    with pytest.raises(ValueError, match="device objects"):
        backend_from_url("sim-usb://inproc")
    with pytest.raises(ValueError, match="inproc"):
        backend_from_url("sim-usb://elsewhere", [])
    assert isinstance(backend_from_url("sim-usb://inproc", []), SimUsbBackend)


def test_bridge_bad_opcode_answers_an_error_frame():
    server = UsbBridgeServer([SimAwg()])
    try:
        with socket.create_connection(("127.0.0.1", server.port)) as s:
            s.sendall(struct.pack("<I", 1) + b"\x63")
            n = struct.unpack("<I", s.recv(4))[0]
            body = b""
            while len(body) < n:
                body += s.recv(n - len(body))
        assert body[0] == 1
        code, _backend_code, is_timeout = struct.unpack_from("<iiB", body, 1)
        assert code == errno.EINVAL and is_timeout == 0
    finally:
        server.close()


def test_bridge_request_golden_framing_bulk_read():
    """The example frame of docs/protocols/usb_sim.md, sent by hand, reads the digitizer stream."""
    dig = SimDigitizer(VirtualClock(), ZeroSource())
    server = UsbBridgeServer([dig])
    try:
        dig.handle_ctrl(0x40, 0x13, 0, 0, struct.pack("<I", 1), 4)   # 1 segment
        dig.handle_ctrl(0x40, 0x20, 0, 0, b"", 0)                    # ARM
        dig.handle_ctrl(0x40, 0x40, 0, 0, bytes.fromhex("00000000 01000000"), 8)
        seg_len = dp.segment_bytes(1, dig.config.record_length, 16)
        with socket.create_connection(("127.0.0.1", server.port)) as s:
            s.sendall(bytes.fromhex("08 00 00 00 05 00 00 81 00 00 10 00"))
            n = struct.unpack("<I", s.recv(4))[0]
            assert n == 1 + seg_len
            body = bytearray()
            while len(body) < n:
                body += s.recv(n - len(body))
        assert body[0] == 0 and body[1:5] == b"DGSG"
    finally:
        server.close()
