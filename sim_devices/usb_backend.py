"""pyusb backends that carry the daemon's USB transfers to simulated instruments.

§4.4.1: the AWG and the ADC hang off the PC's USB bus. The daemon's drivers make ordinary pyusb
calls (``usb.core.find``, ``dev.set_configuration``, ``dev.write``, ``dev.read``,
``dev.ctrl_transfer``); which bus those calls reach is chosen by the backend the configuration
hands to ``usb.core.find``:

* lab:       ``usb.backend.libusb1.get_backend()`` (real hardware, libusb-1.0)
* in-process ``SimUsbBackend(devices=[awg, digitizer])``
* across processes: the bench runs ``UsbBridgeServer(devices)``; the daemon uses
  ``RemoteUsbBackend("tcp://127.0.0.1:PORT")``; framing in docs/protocols/usb_sim.md.

``backend_from_url`` maps a URL to one of these through an explicit scheme table.

Simulated devices subclass ``SimUsbDevice``: they provide descriptors and handle control, bulk-OUT
and bulk-IN transfers. USB failures are raised as pyusb's own exceptions (``USBTimeoutError``,
``USBError`` with errno EPIPE for a stall, ENODEV for a disconnected device) so the drivers exercise
the same error paths as on hardware; tests inject them with ``SimUsbDevice.inject_fault``.
"""

from __future__ import annotations

import errno
import json
import socket
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal
from urllib.parse import urlparse

import usb.backend
import usb.core

FaultKind = Literal["timeout", "stall", "disconnect"]
FaultOp = Literal["ctrl", "bulk_out", "bulk_in", "any"]

# ------------------------------------------------------------------------------- pyusb errors


def usb_timeout(what: str) -> usb.core.USBTimeoutError:
    # libusb1 reports LIBUSB_ERROR_TIMEOUT (-7); pyusb maps it to errno ETIMEDOUT
    return usb.core.USBTimeoutError(f"Operation timed out ({what})", -7, errno.ETIMEDOUT)


def usb_stall(what: str) -> usb.core.USBError:
    return usb.core.USBError(f"Pipe error ({what})", -9, errno.EPIPE)


def usb_nodev(what: str) -> usb.core.USBError:
    return usb.core.USBError(f"No such device (it may have been disconnected) ({what})", -4,
                             errno.ENODEV)


# --------------------------------------------------------------------------------- descriptors


class _Desc:
    """Plain attribute bag: pyusb reads descriptor fields with getattr()."""

    def __init__(self, **fields: object) -> None:
        self.__dict__.update(fields)


@dataclass(frozen=True)
class EndpointSpec:
    address: int
    attributes: int = 0x02  # bulk
    max_packet: int = 512


@dataclass(frozen=True)
class DeviceSpec:
    """What a device says about itself in its descriptors."""

    vid: int
    pid: int
    manufacturer: str
    product: str
    serial: str
    interface_class: int
    interface_subclass: int
    interface_protocol: int
    endpoints: tuple[EndpointSpec, ...]

    def to_json(self) -> dict:
        d = self.__dict__.copy()
        d["endpoints"] = [e.__dict__ for e in self.endpoints]
        return d

    @staticmethod
    def from_json(d: dict) -> DeviceSpec:
        d = dict(d)
        d["endpoints"] = tuple(EndpointSpec(**e) for e in d["endpoints"])
        return DeviceSpec(**d)


def _device_descriptor(spec: DeviceSpec, bus: int, address: int) -> _Desc:
    return _Desc(bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
                 bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=spec.vid, idProduct=spec.pid,
                 bcdDevice=0x0100, iManufacturer=1, iProduct=2, iSerialNumber=3,
                 bNumConfigurations=1, address=address, bus=bus, port_number=address,
                 port_numbers=(address,), speed=3)  # 3 = high speed (480 Mbit/s)


def _config_descriptor(spec: DeviceSpec) -> _Desc:
    return _Desc(bLength=9, bDescriptorType=2, wTotalLength=9 + 9 + 7 * len(spec.endpoints),
                 bNumInterfaces=1, bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80,
                 bMaxPower=250, extra_descriptors=[])


def _interface_descriptor(spec: DeviceSpec) -> _Desc:
    return _Desc(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                 bNumEndpoints=len(spec.endpoints), bInterfaceClass=spec.interface_class,
                 bInterfaceSubClass=spec.interface_subclass,
                 bInterfaceProtocol=spec.interface_protocol, iInterface=0, extra_descriptors=[])


def _endpoint_descriptor(ep: EndpointSpec) -> _Desc:
    return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=ep.address,
                 bmAttributes=ep.attributes, wMaxPacketSize=ep.max_packet, bInterval=0,
                 bRefresh=0, bSynchAddress=0, extra_descriptors=[])


def _string_descriptor(text: str) -> bytes:
    raw = text.encode("utf-16-le")
    return bytes((2 + len(raw), 3)) + raw


# ------------------------------------------------------------------------------ device base


class SimUsbDevice:
    """Base of a simulated USB device: fault injection, string descriptors, a per-device lock.

    Subclasses set ``spec`` and implement ``handle_ctrl``, ``handle_bulk_out``, ``handle_bulk_in``
    (and optionally ``handle_reset`` / ``handle_clear_halt``). The ``usb_*`` methods are what
    backends call; they apply injected faults first.
    """

    spec: DeviceSpec

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._faults: list[tuple[FaultKind, FaultOp]] = []
        self._persistent: list[tuple[FaultKind, FaultOp]] = []  # until cleared
        self.connected = True
        self._gone_for: int | None = None  # transfers left before a timed disconnect ends
        self.faulted_transfers = 0

    # -- fault injection (tests and bench reliability scenarios)
    def inject_fault(self, kind: FaultKind, op: FaultOp = "any", count: int | None = 1) -> None:
        """Make the next ``count`` transfers of type ``op`` fail with ``kind``
        (``count=None``: every such transfer until :meth:`clear_faults`)."""
        if kind not in ("timeout", "stall", "disconnect"):
            raise ValueError(f"unknown USB fault kind {kind!r}")
        if op not in ("ctrl", "bulk_out", "bulk_in", "any"):
            raise ValueError(f"unknown USB transfer type {op!r}")
        if count is not None and (isinstance(count, bool) or int(count) != count or count < 1):
            raise ValueError(f"USB fault count must be an integer >= 1 or None, got {count!r}")
        with self._lock:
            if count is None:
                self._persistent.append((kind, op))
            else:
                self._faults.extend([(kind, op)] * int(count))

    def clear_faults(self, kind: FaultKind | None = None) -> int:
        """Forget injected faults of ``kind`` (all if None); returns how many were pending."""
        with self._lock:
            n = 0
            for lst in (self._faults, self._persistent):
                keep = [f for f in lst if kind is not None and f[0] != kind]
                n += len(lst) - len(keep)
                lst[:] = keep
            return n

    def disconnect(self, transfers: int | None = None) -> None:
        """Unplug: off the bus (not enumerated), every transfer fails with ENODEV. With
        ``transfers`` the device is plugged back in after that many failed transfers."""
        with self._lock:
            self.connected = False
            self._gone_for = None if transfers is None else int(transfers)

    def reconnect(self) -> None:
        """Plug back in. Re-enumeration resets the device's USB-side state (``handle_reset``:
        a USBTMC session, a digitizer stream or armed acquisition); instrument settings (AWG
        waveform, digitizer configuration) survive, as on a self-powered instrument."""
        with self._lock:
            was_gone = not self.connected
            self.connected = True
            self._gone_for = None
            if was_gone:
                self.handle_reset()

    def _gone(self, what: str) -> usb.core.USBError:
        """An access while unplugged: counts toward a timed disconnect's end."""
        self.faulted_transfers += 1
        if self._gone_for is not None:
            self._gone_for -= 1
            if self._gone_for <= 0:
                self.reconnect()
        return usb_nodev(what)

    def _check(self, op: FaultOp, what: str) -> None:
        if not self.connected:
            raise self._gone(what)
        for kind, fop in self._persistent:
            if fop in ("any", op):
                self._fail(kind, what)
        for i, (kind, fop) in enumerate(self._faults):
            if fop in ("any", op):
                del self._faults[i]               # a one-shot fault is used up
                self._fail(kind, what)

    def _fail(self, kind: str, what: str) -> None:
        self.faulted_transfers += 1
        if kind == "timeout":
            raise usb_timeout(what)
        if kind == "stall":
            raise usb_stall(what)
        self.connected = False
        raise usb_nodev(what)

    # -- called by the backends
    def usb_open(self) -> None:
        with self._lock:
            if not self.connected:
                raise self._gone("open")

    def usb_ctrl(self, bm_request_type: int, b_request: int, w_value: int, w_index: int,
                 data: bytes | None, w_length: int) -> bytes | int:
        """OUT (bit 7 clear): ``data`` holds the data stage, returns bytes accepted.
        IN: returns up to ``w_length`` bytes."""
        with self._lock:
            self._check("ctrl", f"ctrl 0x{b_request:02x}")
            if bm_request_type & 0x60 == 0:  # standard request
                return self._standard_request(bm_request_type, b_request, w_value, w_index, w_length)
            return self.handle_ctrl(bm_request_type, b_request, w_value, w_index, data, w_length)

    def usb_bulk_out(self, ep: int, data: memoryview) -> int:
        with self._lock:
            self._check("bulk_out", f"bulk-OUT 0x{ep:02x}")
            return self.handle_bulk_out(ep, data)

    def usb_bulk_in(self, ep: int, buf: memoryview) -> int:
        with self._lock:
            self._check("bulk_in", f"bulk-IN 0x{ep:02x}")
            return self.handle_bulk_in(ep, buf)

    def usb_clear_halt(self, ep: int) -> None:
        with self._lock:
            if not self.connected:
                raise usb_nodev("clear_halt")
            self.handle_clear_halt(ep)

    def usb_reset(self) -> None:
        with self._lock:
            if not self.connected:
                raise usb_nodev("reset")
            self._faults.clear()
            self.handle_reset()

    def _standard_request(self, bm: int, req: int, w_value: int, w_index: int,
                          w_length: int) -> bytes | int:
        if bm & 0x80 and req == 0x06 and (w_value >> 8) == 3:  # GET_DESCRIPTOR(STRING)
            idx = w_value & 0xFF
            if idx == 0:
                return b"\x04\x03\x09\x04"[:w_length]  # langid 0x0409 (en-US)
            strings = {1: self.spec.manufacturer, 2: self.spec.product, 3: self.spec.serial}
            if idx in strings:
                return _string_descriptor(strings[idx])[:w_length]
        raise usb_stall(f"standard request 0x{req:02x}")

    # -- to implement
    def handle_ctrl(self, bm_request_type: int, b_request: int, w_value: int, w_index: int,
                    data: bytes | None, w_length: int) -> bytes | int:
        raise usb_stall(f"vendor request 0x{b_request:02x}")

    def handle_bulk_out(self, ep: int, data: memoryview) -> int:
        raise usb_stall(f"bulk-OUT 0x{ep:02x}")

    def handle_bulk_in(self, ep: int, buf: memoryview) -> int:
        raise usb_stall(f"bulk-IN 0x{ep:02x}")

    def handle_clear_halt(self, ep: int) -> None:
        pass

    def handle_reset(self) -> None:
        pass


# --------------------------------------------------------------------------- in-process backend


class _SimHandle:
    __slots__ = ("index", "open", "config")

    def __init__(self, index: int) -> None:
        self.index = index
        self.open = True
        self.config = 1


class _DescriptorBackend(usb.backend.IBackend):
    """Descriptor half shared by the in-process and remote backends (device id = index)."""

    def _specs(self) -> Sequence[DeviceSpec]:
        raise NotImplementedError

    def _spec(self, dev: int) -> DeviceSpec:
        return self._specs()[dev]

    def get_device_descriptor(self, dev):
        return _device_descriptor(self._spec(dev), bus=1, address=dev + 2)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(f"configuration index {config} (device has one)")
        return _config_descriptor(self._spec(dev))

    def get_interface_descriptor(self, dev, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0:
            raise IndexError(f"interface ({intf},{alt}) of config {config}")
        return _interface_descriptor(self._spec(dev))

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        spec = self._spec(dev)
        if config != 0 or intf != 0 or alt != 0 or not 0 <= ep < len(spec.endpoints):
            raise IndexError(f"endpoint {ep} of interface ({intf},{alt})")
        return _endpoint_descriptor(spec.endpoints[ep])

    def get_parent(self, dev):
        return None

    def set_configuration(self, dev_handle, config_value):
        if config_value not in (0, 1):
            raise usb_stall(f"set_configuration({config_value})")
        dev_handle.config = config_value

    def get_configuration(self, dev_handle):
        return dev_handle.config

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        if intf != 0 or altsetting != 0:
            raise usb_stall(f"set_interface_altsetting({intf},{altsetting})")

    def claim_interface(self, dev_handle, intf):
        if intf != 0:
            raise usb_stall(f"claim_interface({intf})")

    def release_interface(self, dev_handle, intf):
        pass

    def is_kernel_driver_active(self, dev_handle, intf):
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        pass

    def attach_kernel_driver(self, dev_handle, intf):
        pass


class SimUsbBackend(_DescriptorBackend):
    """In-process backend: transfers become method calls on the device objects."""

    def __init__(self, devices: Sequence[SimUsbDevice]) -> None:
        super().__init__()
        self._devices = list(devices)

    def _specs(self) -> Sequence[DeviceSpec]:
        return [d.spec for d in self._devices]

    def enumerate_devices(self):
        return [i for i, d in enumerate(self._devices) if d.connected]

    def open_device(self, dev):
        self._devices[dev].usb_open()
        return _SimHandle(dev)

    def close_device(self, dev_handle):
        dev_handle.open = False

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        return self._devices[dev_handle.index].usb_bulk_out(ep, memoryview(data).cast("B"))

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        return self._devices[dev_handle.index].usb_bulk_in(ep, memoryview(buff).cast("B"))

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        dev = self._devices[dev_handle.index]
        mv = memoryview(data).cast("B")
        if bmRequestType & 0x80:
            reply = dev.usb_ctrl(bmRequestType, bRequest, wValue, wIndex, None, len(mv))
            n = min(len(reply), len(mv))
            mv[:n] = reply[:n]
            return n
        return dev.usb_ctrl(bmRequestType, bRequest, wValue, wIndex, bytes(mv), len(mv))

    def clear_halt(self, dev_handle, ep):
        self._devices[dev_handle.index].usb_clear_halt(ep)

    def reset_device(self, dev_handle):
        self._devices[dev_handle.index].usb_reset()


# --------------------------------------------------------------------------------- the bridge
#
# Frame = u32 LE length of what follows, then the body. Request body: u8 opcode + fixed fields +
# OUT data. Response body: u8 status (0 ok, 1 USB error) + payload. See docs/protocols/usb_sim.md.

OP_ENUMERATE = 1
OP_OPEN = 2
OP_CTRL = 3
OP_BULK_WRITE = 4
OP_BULK_READ = 5
OP_CLEAR_HALT = 6
OP_RESET = 7

_U32 = struct.Struct("<I")
_CTRL = struct.Struct("<BHBBHHI")      # op, dev, bmRequestType, bRequest, wValue, wIndex, wLength
_BULK = struct.Struct("<BHBI")         # op, dev, ep, size (read) / 0 (write)
_DEVOP = struct.Struct("<BHB")         # op, dev, ep (0 when unused)
_ERR = struct.Struct("<iiB")           # errno, backend code, is_timeout
_MAX_FRAME = 256 * 1024 * 1024


def _recv_exact_into(sock: socket.socket, view: memoryview) -> None:
    got = 0
    n = len(view)
    while got < n:
        k = sock.recv_into(view[got:], n - got)
        if k == 0:
            raise ConnectionError("USB bridge connection closed")
        got += k


def _recv_exact(sock: socket.socket, n: int) -> bytearray:
    buf = bytearray(n)
    _recv_exact_into(sock, memoryview(buf))
    return buf


def _send_frame(sock: socket.socket, *parts: bytes | bytearray | memoryview) -> None:
    total = sum(len(p) for p in parts)
    head = _U32.pack(total) + bytes(parts[0])
    sock.sendall(head)
    for p in parts[1:]:
        if len(p):
            sock.sendall(p)


def _error_body(exc: usb.core.USBError) -> bytes:
    code = exc.errno if exc.errno is not None else errno.EIO
    backend_code = exc.backend_error_code if exc.backend_error_code is not None else -99
    timeout = isinstance(exc, usb.core.USBTimeoutError)
    return b"\x01" + _ERR.pack(code, backend_code, int(timeout)) + str(exc.strerror).encode()


class UsbBridgeServer:
    """Serves simulated devices to ``RemoteUsbBackend`` clients over TCP (bench side).

    One thread accepts; one thread per connection handles requests in order. Each device's own
    lock serializes transfers to it, exactly one request at a time per device as on a real bus.
    """

    def __init__(self, devices: Sequence[SimUsbDevice], host: str = "127.0.0.1", port: int = 0) -> None:
        self._devices = list(devices)
        self._sock = socket.create_server((host, port))
        self.host, self.port = self._sock.getsockname()[:2]
        self._threads: list[threading.Thread] = []
        self._conns: list[socket.socket] = []
        self._closed = threading.Event()
        self._accept = threading.Thread(target=self._serve, name="usb-bridge-accept", daemon=True)
        self._accept.start()

    @property
    def url(self) -> str:
        return f"sim-usb+tcp://{self.host}:{self.port}"

    def _serve(self) -> None:
        while not self._closed.is_set():
            try:
                conn, _ = self._sock.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._conns.append(conn)
            t = threading.Thread(target=self._handle, args=(conn,), name="usb-bridge-conn", daemon=True)
            self._threads.append(t)
            t.start()

    def _handle(self, conn: socket.socket) -> None:
        scratch = bytearray(1 << 20)
        try:
            while True:
                n = _U32.unpack(_recv_exact(conn, 4))[0]
                if n == 0 or n > _MAX_FRAME:
                    return
                req = _recv_exact(conn, n)
                scratch = self._dispatch(conn, req, scratch)
        except (ConnectionError, OSError):
            return
        finally:
            conn.close()

    def _dispatch(self, conn: socket.socket, req: bytearray, scratch: bytearray) -> bytearray:
        op = req[0]
        try:
            if op == OP_ENUMERATE:
                listing = [{"index": i, "spec": d.spec.to_json()}
                           for i, d in enumerate(self._devices) if d.connected]
                _send_frame(conn, b"\x00" + json.dumps(listing).encode())
            elif op == OP_OPEN:
                _, dev, _ = _DEVOP.unpack_from(req)
                self._devices[dev].usb_open()
                _send_frame(conn, b"\x00")
            elif op == OP_CTRL:
                _, dev, bm, breq, wv, wi, wl = _CTRL.unpack_from(req)
                data = bytes(req[_CTRL.size:]) if not bm & 0x80 else None
                r = self._devices[dev].usb_ctrl(bm, breq, wv, wi, data, wl)
                if bm & 0x80:
                    _send_frame(conn, b"\x00", bytes(r[:wl]))
                else:
                    _send_frame(conn, b"\x00" + _U32.pack(int(r)))
            elif op == OP_BULK_WRITE:
                _, dev, ep, _ = _BULK.unpack_from(req)
                k = self._devices[dev].usb_bulk_out(ep, memoryview(req)[_BULK.size:])
                _send_frame(conn, b"\x00" + _U32.pack(k))
            elif op == OP_BULK_READ:
                _, dev, ep, size = _BULK.unpack_from(req)
                if size > len(scratch):
                    scratch = bytearray(size)
                view = memoryview(scratch)[:size]
                k = self._devices[dev].usb_bulk_in(ep, view)
                _send_frame(conn, b"\x00", view[:k])
            elif op == OP_CLEAR_HALT:
                _, dev, ep = _DEVOP.unpack_from(req)
                self._devices[dev].usb_clear_halt(ep)
                _send_frame(conn, b"\x00")
            elif op == OP_RESET:
                _, dev, _ = _DEVOP.unpack_from(req)
                self._devices[dev].usb_reset()
                _send_frame(conn, b"\x00")
            else:
                _send_frame(conn, _error_body(usb.core.USBError(f"bad bridge opcode {op}", -99, errno.EINVAL)))
        except usb.core.USBError as exc:
            _send_frame(conn, _error_body(exc))
        except (IndexError, struct.error) as exc:
            _send_frame(conn, _error_body(usb.core.USBError(f"bad bridge request: {exc}", -99, errno.EINVAL)))
        return scratch

    def close(self) -> None:
        self._closed.set()
        try:
            # shutdown (not just close) wakes the thread blocked in accept() on Linux
            self._sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self._sock.close()
        for c in list(self._conns):
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()
        self._accept.join(timeout=5)
        for t in self._threads:
            t.join(timeout=5)

    def __enter__(self) -> UsbBridgeServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RemoteUsbBackend(_DescriptorBackend):
    """Daemon-side backend that forwards every transfer to a ``UsbBridgeServer``."""

    def __init__(self, url: str, connect_timeout_s: float = 5.0) -> None:
        super().__init__()
        u = urlparse(url)
        if u.scheme not in ("tcp", "sim-usb+tcp") or u.hostname is None or u.port is None:
            raise ValueError(f"RemoteUsbBackend URL must be tcp://HOST:PORT, got {url!r}")
        self._sock = socket.create_connection((u.hostname, u.port), timeout=connect_timeout_s)
        self._sock.settimeout(None)
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._lock = threading.Lock()
        self._spec_by_index: dict[int, DeviceSpec] = {}

    def close(self) -> None:
        self._sock.close()

    def _specs(self):
        return self._spec_by_index

    # one request, one response; returns the payload after the status byte
    def _call(self, *parts: bytes | bytearray | memoryview) -> bytearray:
        with self._lock:
            try:
                _send_frame(self._sock, *parts)
                n = _U32.unpack(_recv_exact(self._sock, 4))[0]
                body = _recv_exact(self._sock, n)
            except OSError as exc:  # ConnectionError included
                raise self._bench_gone(exc) from exc
        self._raise_if_error(body)
        return body

    @staticmethod
    def _bench_gone(exc: OSError) -> usb.core.USBError:
        # the bench process went away: to the driver that is a device unplugged from the bus
        return usb_nodev(f"USB bridge connection lost: {exc}")

    @staticmethod
    def _raise_if_error(body: bytearray) -> None:
        if body[0] == 0:
            return
        code, backend_code, timeout = _ERR.unpack_from(body, 1)
        text = bytes(body[1 + _ERR.size:]).decode("utf-8", "replace")
        cls = usb.core.USBTimeoutError if timeout else usb.core.USBError
        raise cls(text, backend_code, code)

    def enumerate_devices(self):
        body = self._call(bytes([OP_ENUMERATE]))
        listing = json.loads(bytes(body[1:]).decode())
        for item in listing:
            self._spec_by_index[item["index"]] = DeviceSpec.from_json(item["spec"])
        return [item["index"] for item in listing]

    def open_device(self, dev):
        self._call(_DEVOP.pack(OP_OPEN, dev, 0))
        return _SimHandle(dev)

    def close_device(self, dev_handle):
        dev_handle.open = False

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        body = self._call(_BULK.pack(OP_BULK_WRITE, dev_handle.index, ep, 0), memoryview(data).cast("B"))
        return _U32.unpack_from(body, 1)[0]

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        mv = memoryview(buff).cast("B")
        with self._lock:
            try:
                _send_frame(self._sock, _BULK.pack(OP_BULK_READ, dev_handle.index, ep, len(mv)))
                n = _U32.unpack(_recv_exact(self._sock, 4))[0]
                status = _recv_exact(self._sock, 1)
                if status[0] != 0:
                    body = status + _recv_exact(self._sock, n - 1)
                else:
                    # the payload lands straight in the caller's buffer: no intermediate copy
                    _recv_exact_into(self._sock, mv[:n - 1])
                    return n - 1
            except OSError as exc:
                raise self._bench_gone(exc) from exc
        self._raise_if_error(body)
        return 0  # unreachable

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        mv = memoryview(data).cast("B")
        hdr = _CTRL.pack(OP_CTRL, dev_handle.index, bmRequestType, bRequest, wValue, wIndex, len(mv))
        if bmRequestType & 0x80:
            body = self._call(hdr)
            reply = body[1:]
            n = min(len(reply), len(mv))
            mv[:n] = reply[:n]
            return n
        body = self._call(hdr, bytes(mv))
        return _U32.unpack_from(body, 1)[0]

    def clear_halt(self, dev_handle, ep):
        self._call(_DEVOP.pack(OP_CLEAR_HALT, dev_handle.index, ep))

    def reset_device(self, dev_handle):
        self._call(_DEVOP.pack(OP_RESET, dev_handle.index, 0))


# ----------------------------------------------------------------------------------- URLs


def _libusb1(_url: str, _devices: Sequence[SimUsbDevice] | None) -> usb.backend.IBackend:
    import usb.backend.libusb1

    backend = usb.backend.libusb1.get_backend()
    if backend is None:
        raise ValueError("libusb1:// requested but libusb-1.0 is not available on this host")
    return backend


def _inproc(url: str, devices: Sequence[SimUsbDevice] | None) -> usb.backend.IBackend:
    if devices is None:
        raise ValueError(f"{url!r} needs the simulated device objects (composition root only)")
    return SimUsbBackend(devices)


def _tcp(url: str, _devices: Sequence[SimUsbDevice] | None) -> usb.backend.IBackend:
    return RemoteUsbBackend(url)


_SCHEMES = {"libusb1": _libusb1, "sim-usb": _inproc, "sim-usb+tcp": _tcp}


def backend_from_url(url: str, devices: Sequence[SimUsbDevice] | None = None) -> usb.backend.IBackend:
    """``libusb1://`` (lab), ``sim-usb://inproc`` (needs ``devices``),
    ``sim-usb+tcp://HOST:PORT`` (a bench's UsbBridgeServer)."""
    scheme = urlparse(url).scheme
    try:
        factory = _SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"unknown USB backend URL scheme {scheme!r} in {url!r}; "
                         f"expected one of {sorted(_SCHEMES)}") from None
    if scheme == "sim-usb" and urlparse(url).netloc != "inproc":
        raise ValueError(f"sim-usb URL must be sim-usb://inproc, got {url!r}")
    return factory(url, devices)
