"""Fault injection on the simulated bench (issue 6; catalogue and parameters in ``sim_devices.faults``).

:class:`BenchFaults` is the fault half of :class:`sim_devices.bench.bench.Bench`: ``inject_fault(kind,
**params) -> dict``, ``clear_faults(kind=None) -> int``, ``active_faults()``, and what each kind does
to the devices (serial line noise, the FPGA's pty vanishing and coming back, USB faults, digitizer
overrange gain, Modbus exceptions and timeouts, the interlock opening at a virtual time or after a
number of segments, stuck MEMS switches, the HV fault, a TEC offset). Faults of the kinds in
``_SINGLETONS`` are one per bench: injecting one again replaces the earlier one (its ``id``
changes). Count-limited faults (``n``) drop out of ``active_faults()`` once used up. Timed ends run
on the bench's virtual clock. The mixin uses the bench's ``clock``, ``profile``, ``controller``,
``fpga``, ``awg``, ``digitizer``, ``serial_line``, ``segments_synthesized``, its pty helpers
(``_open_pty``, ``_drop_pty``) and the fault bookkeeping set up in ``Bench.__init__``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.controller import protocol as ctl_p

from sim_devices.faults import FAULT_KINDS, validate_fault

# Faults of which a bench holds at most one: a second injection replaces the first.
_SINGLETONS = ("serial_drop", "serial_flip", "serial_disconnect", "digitizer_overrange", "hv_fault",
               "interlock_open", "tec_offset")
_USB_KIND = {"usb_timeout": "timeout", "usb_stall": "stall", "usb_disconnect": "disconnect"}


class BenchFaults:
    """Fault injection of the simulated bench (a mixin of :class:`~sim_devices.bench.bench.Bench`)."""

    def inject_fault(self, kind: str, **params: Any) -> dict[str, Any]:
        """Inject a fault (catalogue: ``sim_devices.faults``); returns it as a dict with an ``id``.

        Raises ``ValueError`` naming the kind or parameter if it is unknown or bad (nothing is
        changed then)."""
        spec = validate_fault(kind, params)
        with self._fault_lock:
            if kind == "stuck_switch":
                n = self.profile.rows if spec["line"] == "row" else self.profile.cols
                if spec["index"] >= n:
                    raise ValueError(f"fault stuck_switch: index must be 0..{n - 1} for a "
                                     f"{spec['line']}, got {spec['index']}")
            if kind in _SINGLETONS:
                for fid, rec in list(self._faults.items()):
                    if rec["kind"] == kind:
                        self._undo(fid, rec, replacing=True)
            fid = next(self._fault_ids)
            rec = {"id": fid, **spec, "since_s": self.clock.now()}
            self._faults[fid] = rec
            self._apply(fid, rec)
            return dict(rec)

    def clear_faults(self, kind: str | None = None) -> int:
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

    def active_faults(self) -> list[dict[str, Any]]:
        with self._fault_lock:
            self._prune()
            return [dict(r) for r in self._faults.values()]

    def _usb_device(self, name: str):
        return self.awg if name == "awg" else self.digitizer

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
                done = not self.controller._pending_exceptions
            elif k == "modbus_timeout" and rec["n"] is not None:
                done = self.controller._pending_timeouts == 0
            if done:
                del self._faults[fid]

    def _apply(self, fid: int, rec: dict[str, Any]) -> None:
        k = rec["kind"]
        if k == "serial_drop":
            self.serial_line.drop_rate = rec["rate"]
        elif k == "serial_flip":
            self.serial_line.flip_rate = rec["rate"]
        elif k == "serial_disconnect":
            self._drop_pty()
            if rec["reconnect_after_s"] is not None:
                self._timers[fid] = self.clock.call_at(
                    rec["since_s"] + rec["reconnect_after_s"], lambda: self._expire(fid))
        elif k in _USB_KIND:
            dev = self._usb_device(rec["device"])
            if k == "usb_disconnect":
                dev.disconnect(rec["n"])
            else:
                dev.inject_fault(_USB_KIND[k], "any", rec["n"])
        elif k == "digitizer_overrange":
            self._overrange_gain = rec["gain"]
        elif k == "modbus_exception":
            self.controller.inject_exception(rec["code"], rec["n"])
        elif k == "modbus_timeout":
            self.controller.inject_timeout(rec["n"])
        elif k == "interlock_open":
            self._interlock_fid = fid
            now = self.clock.now()
            if rec["after_segments"] is not None:
                self._interlock_after = self.segments_synthesized + rec["after_segments"]
            elif rec["at_s"] is not None and rec["at_s"] > now:
                self._interlock_at_s = rec["at_s"]
                self._timers[fid] = self.clock.call_at(rec["at_s"], self._open_interlock)
            else:
                self._open_interlock()
        elif k == "stuck_switch":
            self.fpga.stick_switch(rec["line"], rec["index"], rec["state"] == "on")
        elif k == "hv_fault":
            self.controller.set_fault_cause(ctl_p.Fault.HV_FAULT, True)
        elif k == "tec_offset":
            self.controller.model.tec_offset_c = rec["offset_c"]

    def _undo(self, fid: int, rec: dict[str, Any], *, replacing: bool = False) -> None:
        self._faults.pop(fid, None)
        handle = self._timers.pop(fid, None)
        if handle is not None:
            self.clock.cancel(handle)
        k = rec["kind"]
        if k == "serial_drop":
            self.serial_line.drop_rate = 0.0
        elif k == "serial_flip":
            self.serial_line.flip_rate = 0.0
        elif k == "serial_disconnect":
            if self._pty is None and self.fpsa_link is not None:
                self._open_pty()
        elif k in _USB_KIND:
            dev = self._usb_device(rec["device"])
            if k == "usb_disconnect":
                dev.reconnect()
            else:
                dev.clear_faults(_USB_KIND[k])
        elif k == "digitizer_overrange":
            self._overrange_gain = 1.0
        elif k == "modbus_exception":
            self.controller.clear_injected("exception")
        elif k == "modbus_timeout":
            self.controller.clear_injected("timeout")
        elif k == "interlock_open":
            self._interlock_at_s = self._interlock_after = self._interlock_fid = None
            if not replacing:
                self.controller.set_interlock(True)
        elif k == "stuck_switch":
            self.fpga.release_switch(rec["line"], rec["index"])
        elif k == "hv_fault":
            self.controller.set_fault_cause(ctl_p.Fault.HV_FAULT, False)
        elif k == "tec_offset":
            self.controller.model.tec_offset_c = 0.0

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
        self.controller.set_interlock(False)

    def _interlock_cut_s(self, t_s: np.ndarray) -> float | None:
        """Trigger time from which an interlock opening darkens this batch (None: it does not)."""
        with self._fault_lock:
            if self._interlock_after is not None and len(t_s):
                k = self._interlock_after - self.segments_synthesized
                if k < len(t_s):
                    cut = float(t_s[max(k, 0)])
                    self._open_interlock()  # the loop opens now: later batches see it tripped
                    return cut
            if self._interlock_at_s is not None and len(t_s) and t_s[-1] >= self._interlock_at_s:
                return self._interlock_at_s  # the clock timer trips the controller at at_s
            return None
