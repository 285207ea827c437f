"""Base of a simulated USB device on the bench's USB bus (§4.4.1: the AWG and the ADC).

Simulated devices (``sim_devices.awg.device``, ``sim_devices.digitizer.device``) subclass :class:`SimUsbDevice`:
they set a :class:`~sim_devices.usb.descriptors.DeviceSpec` and handle control, bulk-OUT and bulk-IN
transfers; the base answers the standard string-descriptor requests, holds a per-device lock and
applies injected faults before every transfer. USB failures are raised as pyusb's own exceptions
(``USBTimeoutError``, ``USBError`` with errno EPIPE for a stall, ENODEV for a disconnected device;
``sim_devices.usb.errors``) so the drivers exercise the same error paths as on hardware; tests
inject them with :meth:`SimUsbDevice.inject_fault`.
"""

from __future__ import annotations

import threading
from typing import Literal

import usb.core

from sim_devices.usb.descriptors import DeviceSpec, _string_descriptor
from sim_devices.usb.errors import usb_nodev, usb_stall, usb_timeout

FaultKind = Literal["timeout", "stall", "disconnect"]
FaultOp = Literal["ctrl", "bulk_out", "bulk_in", "any"]


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
