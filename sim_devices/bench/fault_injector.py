"""Fault injection on the simulated bench (catalogue and parameters in ``sim_devices.faults``).

:class:`FaultInjector` is held by :class:`sim_devices.bench.bench.Bench` as ``bench.faults``:
``inject(kind, **params) -> dict``, ``clear(kind=None) -> int``, ``active()``, and what each kind does
to the devices (serial line noise, the FPGA's pty vanishing and coming back, USB faults, digitizer
overrange gain, Modbus exceptions and timeouts, the interlock opening at a virtual time or after a
number of segments, stuck MEMS switches, the HV fault, a TEC offset). Faults of the kinds in
``_SINGLETONS`` are one per bench: injecting one again replaces the earlier one (its ``id``
changes). Count-limited faults (``n``) drop out of ``active()`` once used up. Timed ends run on the
bench's virtual clock. The injector is given every device it acts on (:class:`FaultTargets`) and the
FPGA's serial port (:class:`SerialPort`); the segment synthesis asks it for the overrange gain and
where an interlock opening cuts a batch.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from drivers.controller import protocol as ctl_p
from sim_devices.awg.device import SimAwg
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim
from sim_devices.digitizer.device import SimDigitizer
from sim_devices.faults import FAULT_KINDS, SerialLineNoise, validate_fault
from sim_devices.fpsa.device import FpgaSim
from sim_devices.usb.device import FaultKind

# Faults of which a bench holds at most one: a second injection replaces the first.
_SINGLETONS = ("serial_drop", "serial_flip", "serial_disconnect", "digitizer_overrange", "hv_fault",
               "interlock_open", "tec_offset")
_USB_KIND: dict[str, FaultKind] = {"usb_timeout": "timeout", "usb_stall": "stall", "usb_disconnect": "disconnect"}


class SerialPort(Protocol):
    """The FPGA's serial port as the bench publishes it: a ``serial_disconnect`` drops it, clearing
    the fault opens it again (on a new pty, behind the same path)."""

    @property
    def is_open(self) -> bool: ...

    @property
    def published(self) -> bool: ...

    def open(self) -> None: ...

    def drop(self) -> None: ...


@dataclass(frozen=True)
class FaultTargets:
    """What the faults act on: the devices, the serial line's noise, the array's size (a stuck
    switch's index is checked against it) and the count of segments synthesized so far (an
    interlock opening ``after_segments`` counts from it)."""

    clock: VirtualClock
    fpga: FpgaSim
    awg: SimAwg
    digitizer: SimDigitizer
    controller: ControllerSim
    serial_line: SerialLineNoise
    port: SerialPort
    rows: int
    cols: int
    segments_synthesized: Callable[[], int]


class FaultInjector:
    """The simulated bench's active faults and their effects on its devices."""

    def __init__(self, targets: FaultTargets) -> None:
        self._t = targets
        self._faults: dict[int, dict[str, Any]] = {}
        self._fault_ids = itertools.count(1)
        self._fault_lock = threading.RLock()
        self._timers: dict[int, int] = {}          # fault id -> clock timer handle
        #: the gain a ``digitizer_overrange`` fault puts on the returns (1 without one)
        self.overrange_gain = 1.0
        self._interlock_at_s: float | None = None      # a timed opening not yet reached
        self._interlock_after: int | None = None       # open when segments_synthesized reaches this
        self._interlock_fid: int | None = None

    def close(self) -> None:
        """Cancel the timed ends of the faults (the bench is closing)."""
        for handle in list(self._timers.values()):
            self._t.clock.cancel(handle)
        self._timers.clear()

    def inject(self, kind: str, **params: Any) -> dict[str, Any]:
        """Inject a fault (catalogue: ``sim_devices.faults``); returns it as a dict with an ``id``.

        Raises ``ValueError`` naming the kind or parameter if it is unknown or bad (nothing is
        changed then)."""
        spec = validate_fault(kind, params)
        with self._fault_lock:
            if kind == "stuck_switch":
                n = self._t.rows if spec["line"] == "row" else self._t.cols
                if spec["index"] >= n:
                    raise ValueError(f"fault stuck_switch: index must be 0..{n - 1} for a "
                                     f"{spec['line']}, got {spec['index']}")
            if kind in _SINGLETONS:
                for fid, rec in list(self._faults.items()):
                    if rec["kind"] == kind:
                        self._undo(fid, rec, replacing=True)
            fid = next(self._fault_ids)
            rec = {"id": fid, **spec, "since_s": self._t.clock.now()}
            self._faults[fid] = rec
            self._apply(fid, rec)
            return dict(rec)

    def clear(self, kind: str | None = None) -> int:
        """Clear active faults of ``kind`` (all if None) and restore normal behaviour; returns
        how many were cleared."""
        if kind is not None and kind not in FAULT_KINDS:
            raise ValueError(f"unknown fault kind {kind!r}; known: {', '.join(FAULT_KINDS)}")
        with self._fault_lock:
            self._prune()
            n = 0
            for fid, rec in list(self._faults.items()):
                if kind is None or rec["kind"] == kind:
                    self._undo(fid, rec)
                    n += 1
            return n

    def active(self) -> list[dict[str, Any]]:
        with self._fault_lock:
            self._prune()
            return [dict(r) for r in self._faults.values()]

    def _usb_device(self, name: str) -> SimAwg | SimDigitizer:
        return self._t.awg if name == "awg" else self._t.digitizer

    def _prune(self) -> None:
        """Forget count-limited faults whose count is used up (their effect is over)."""
        for fid, rec in list(self._faults.items()):
            k = rec["kind"]
            done = False
            if k in _USB_KIND and rec["n"] is not None:
                dev = self._usb_device(rec["device"])
                if k == "usb_disconnect":
                    done = dev.connected
                else:
                    done = not any(f[0] == _USB_KIND[k] for f in dev._faults)
            elif k == "modbus_exception" and rec["n"] is not None:
                done = not self._t.controller._pending_exceptions
            elif k == "modbus_timeout" and rec["n"] is not None:
                done = self._t.controller._pending_timeouts == 0
            if done:
                del self._faults[fid]

    def _apply(self, fid: int, rec: dict[str, Any]) -> None:
        k = rec["kind"]
        if k == "serial_drop":
            self._t.serial_line.drop_rate = rec["rate"]
        elif k == "serial_flip":
            self._t.serial_line.flip_rate = rec["rate"]
        elif k == "serial_disconnect":
            self._t.port.drop()
            if rec["reconnect_after_s"] is not None:
                self._timers[fid] = self._t.clock.call_at(
                    rec["since_s"] + rec["reconnect_after_s"], lambda: self._expire(fid))
        elif k in _USB_KIND:
            dev = self._usb_device(rec["device"])
            if k == "usb_disconnect":
                dev.disconnect(rec["n"])
            else:
                dev.inject_fault(_USB_KIND[k], "any", rec["n"])
        elif k == "digitizer_overrange":
            self.overrange_gain = rec["gain"]
        elif k == "modbus_exception":
            self._t.controller.inject_exception(rec["code"], rec["n"])
        elif k == "modbus_timeout":
            self._t.controller.inject_timeout(rec["n"])
        elif k == "interlock_open":
            self._interlock_fid = fid
            now = self._t.clock.now()
            if rec["after_segments"] is not None:
                self._interlock_after = self._t.segments_synthesized() + rec["after_segments"]
            elif rec["at_s"] is not None and rec["at_s"] > now:
                self._interlock_at_s = rec["at_s"]
                self._timers[fid] = self._t.clock.call_at(rec["at_s"], self._open_interlock)
            else:
                self._open_interlock()
        elif k == "stuck_switch":
            self._t.fpga.stick_switch(rec["line"], rec["index"], rec["state"] == "on")
        elif k == "hv_fault":
            self._t.controller.set_fault_cause(ctl_p.Fault.HV_FAULT, True)
        elif k == "tec_offset":
            self._t.controller.model.tec_offset_c = rec["offset_c"]

    def _undo(self, fid: int, rec: dict[str, Any], *, replacing: bool = False) -> None:
        self._faults.pop(fid, None)
        handle = self._timers.pop(fid, None)
        if handle is not None:
            self._t.clock.cancel(handle)
        k = rec["kind"]
        if k == "serial_drop":
            self._t.serial_line.drop_rate = 0.0
        elif k == "serial_flip":
            self._t.serial_line.flip_rate = 0.0
        elif k == "serial_disconnect":
            if not self._t.port.is_open and self._t.port.published:
                self._t.port.open()
        elif k in _USB_KIND:
            dev = self._usb_device(rec["device"])
            if k == "usb_disconnect":
                dev.reconnect()
            else:
                dev.clear_faults(_USB_KIND[k])
        elif k == "digitizer_overrange":
            self.overrange_gain = 1.0
        elif k == "modbus_exception":
            self._t.controller.clear_injected("exception")
        elif k == "modbus_timeout":
            self._t.controller.clear_injected("timeout")
        elif k == "interlock_open":
            self._interlock_at_s = self._interlock_after = self._interlock_fid = None
            if not replacing:
                self._t.controller.set_interlock(True)
        elif k == "stuck_switch":
            self._t.fpga.release_switch(rec["line"], rec["index"])
        elif k == "hv_fault":
            self._t.controller.set_fault_cause(ctl_p.Fault.HV_FAULT, False)
        elif k == "tec_offset":
            self._t.controller.model.tec_offset_c = 0.0

    def _expire(self, fid: int) -> None:
        """A fault that ends by itself (``reconnect_after_s``)."""
        with self._fault_lock:
            rec = self._faults.get(fid)
            if rec is not None:
                self._timers.pop(fid, None)
                self._undo(fid, rec)

    def _open_interlock(self) -> None:
        self._interlock_at_s = None
        self._interlock_after = None
        self._t.controller.set_interlock(False)

    def interlock_cut_s(self, t_s: np.ndarray, segments_before: int) -> float | None:
        """Trigger time from which an interlock opening darkens this batch of triggers at ``t_s``,
        ``segments_before`` segments having been synthesized before it (None: it does not)."""
        with self._fault_lock:
            if self._interlock_after is not None and len(t_s):
                k = self._interlock_after - segments_before
                if k < len(t_s):
                    cut = float(t_s[max(k, 0)])
                    self._open_interlock()  # the loop opens now: later batches see it tripped
                    return cut
            if self._interlock_at_s is not None and len(t_s) and t_s[-1] >= self._interlock_at_s:
                return self._interlock_at_s  # the clock timer trips the controller at at_s
            return None
