"""Host-side channels to a simulated FPSA board: an in-memory serial port and a pty server.

The FPGA simulator (:class:`sim_devices.fpsa.device.FpgaSim`) is a byte handler (``feed(bytes) -> bytes``);
these wrap it in what a driver opens. :class:`SimSerial` behaves like a pyserial port for tests (a
read returns what is buffered, as a real port does when its timeout expires, so no wall-clock
wait); :class:`PtyServer` serves the handler on a pseudo-terminal whose slave path the driver opens
like any serial device. Both take an optional :class:`~sim_devices.faults.SerialLineNoise` that
corrupts the bytes of both directions.
"""

from __future__ import annotations

import os
import select
import threading
import tty
from typing import Protocol

from sim_devices.faults import SerialLineNoise


class ByteHandler(Protocol):
    """A byte-level device peer: consumes the host's bytes, returns its answer (maybe empty)."""

    def feed(self, data: bytes) -> bytes: ...


class SimSerial:
    """In-memory serial-like channel to an :class:`~sim_devices.fpsa.device.FpgaSim` (write -> device -> read buffer).

    ``read`` returns what is buffered, possibly nothing, as a real port does when its read
    timeout expires, so a driver's timeout logic runs without any wall-clock wait.
    """

    def __init__(self, sim: ByteHandler, line: SerialLineNoise | None = None) -> None:
        self.sim = sim
        self.line = line
        self.timeout: float | None = 0.0
        self.is_open = True
        self._rx = bytearray()

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise OSError("SimSerial is closed")
        data = bytes(data)
        if self.line is None:
            self._rx += self.sim.feed(data)
        else:
            self._rx += self.line.apply(self.sim.feed(self.line.apply(data)))
        return len(data)

    def read(self, size: int = 1) -> bytes:
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def reset_input_buffer(self) -> None:
        self._rx.clear()

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False


class PtyServer:
    """Serve an :class:`~sim_devices.fpsa.device.FpgaSim` on a pseudo-terminal; open :attr:`path` like a serial device.

    A thread reads the master side, feeds the simulator and writes its answers back. The slave
    fd stays open here so the pty does not hang up when the driver closes and reopens it.
    ``line`` (optional) corrupts the bytes of both directions. :meth:`close` closes the master:
    the device is gone, and host reads/writes on the slave fail (EIO) from then on.
    """

    def __init__(self, sim: ByteHandler, line: SerialLineNoise | None = None) -> None:
        self.sim = sim
        self.line = line
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._closed = False
        self._thread = threading.Thread(target=self._serve, name=f"fpga-pty {self.path}",
                                        daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        while True:
            ready, _, _ = select.select([self._master, self._wake_r], [], [])
            if self._wake_r in ready:
                return
            try:
                data = os.read(self._master, 65536)
            except OSError:
                return
            if not data:
                return
            line = self.line
            if line is not None:
                data = line.apply(data)
            resp = self.sim.feed(data) if data else b""
            if line is not None:
                resp = line.apply(resp)
            view = memoryview(resp)
            while view:
                n = os.write(self._master, view)
                view = view[n:]

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        os.write(self._wake_w, b"x")
        self._thread.join(timeout=5)
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            os.close(fd)

    def __enter__(self) -> PtyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
