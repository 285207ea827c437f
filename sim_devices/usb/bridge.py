"""The USB bridge: a simulated bench's USB devices served over a local socket, and the pyusb backend
on the daemon's side that reaches them (``sim-usb+tcp://HOST:PORT``; framing in
docs/protocols/usb_sim.md).

The bench process runs :class:`UsbBridgeServer` (one thread per connection, transfers become method
calls on the device objects); the daemon passes :class:`RemoteUsbBackend` to ``usb.core.find``. A USB
error on the bench side travels back as its errno, backend code and timeout flag and is re-raised as
the same pyusb exception; a bench that went away is ENODEV. Only loopback is intended (no
authentication).
"""

from __future__ import annotations

import errno
import json
import socket
import struct
import threading
from collections.abc import Sequence
from urllib.parse import urlparse

import usb.core

from sim_devices.usb.descriptors import DeviceSpec, _DescriptorBackend, _SimHandle
from sim_devices.usb.device import SimUsbDevice
from sim_devices.usb.errors import usb_nodev

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
        self._lock = threading.Lock()
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
            t = threading.Thread(target=self._handle, args=(conn,), name="usb-bridge-conn", daemon=True)
            with self._lock:
                self._conns.append(conn)
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
            # a bench serves daemons for weeks, one connection per daemon session: a finished
            # connection leaves nothing behind
            with self._lock:
                if conn in self._conns:
                    self._conns.remove(conn)
                me = threading.current_thread()
                if me in self._threads:
                    self._threads.remove(me)

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
        with self._lock:
            conns, threads = list(self._conns), list(self._threads)
        for c in conns:
            try:
                c.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            c.close()
        self._accept.join(timeout=5)
        for t in threads:
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
