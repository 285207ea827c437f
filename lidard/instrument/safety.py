"""The safety monitor: interlock/fault check and the safe-state path (issue 6; docs/reliability.md).

The laser and the FPSA's high-voltage switch drive (dissertation §4.3.3: the HV583 converters behind
the FPGA that drive the MEMS actuators) are the two outputs that must go down when
the interlock opens or the controller latches a fault. :meth:`SafetyMonitor.check` is one Modbus
request (the controller's flags); :meth:`SafetyMonitor.trip` commands laser off and HV off FIRST,
then reads both back. The controller's own hardware interlock drops the outputs at once anyway; this
is the host's view of it, so the points measured while the light was unknown are discarded.

Today the scan loop calls ``check()`` between digitizer reads (at most ``SAFETY_CHECK_S`` of
hardware time apart). The class holds no scan state, so it can be driven from its own wall-clock
thread instead; all its methods talk only to the controller.
"""

from __future__ import annotations

from typing import Any, Callable

from drivers.controller.driver import SettleCheck

from ..selftest_analysis import hv_margin_problem
from .errors import InstrumentError


class SafetyMonitor:
    """Interlock/fault check, safe state, and bringing the laser and HV up and down."""

    def __init__(self, controller: Any, *, laser_current_ma: float, hv_v: float,
                 sleep: Callable[[float], object], now: Callable[[], float],
                 pull_in_v: float | None = None, spread_v: float = 0.0):
        self.controller = controller
        self.laser_current_ma = laser_current_ma     # setpoints of bring_up()
        self.hv_v = hv_v
        self.pull_in_v = pull_in_v                   # the switches' pull-in (profile), checked at bring-up
        self.spread_v = spread_v
        self._sleep = sleep
        self._now = now

    def settle(self) -> SettleCheck:
        """The controller's readback wait, on the instrument's clock (virtual on a bench)."""
        return SettleCheck(sleep=self._sleep, timeout_s=30.0, poll_s=0.002)

    # -- the check and the trip -------------------------------------------------------------------
    def check(self) -> str | None:
        """One Modbus request: None when the interlock is closed and no fault is latched."""
        try:
            flags = self.controller.flags()
        except Exception as exc:
            # cannot see the interlock: treat as unsafe (fail safe)
            return f"controller: interlock state unreadable ({type(exc).__name__}: {exc})"
        if not flags.interlock_closed:
            return "controller: interlock opened mid-scan"
        if flags.fault_active:
            try:
                names = sorted(f.name for f in self.controller.faults())
            except Exception:
                names = ["unknown"]
            return f"controller: fault latched mid-scan ({', '.join(names)})"
        return None

    def trip(self) -> dict[str, Any]:
        """Laser off and HV off commanded FIRST, then both read back; returns the readbacks."""
        errors = []
        for what, fn in (("laser off", lambda: self.controller.laser_enable(False)),
                         ("HV off", lambda: self.controller.hv_enable(False))):
            try:
                fn()
            except Exception as exc:
                errors.append(f"{what}: {type(exc).__name__}: {exc}")
        t_cmd = float(self._now())      # read after the commands: nothing may delay them
        try:
            self.controller.bring_down(settle_check=self.settle())
        except Exception as exc:
            errors.append(f"bring down: {type(exc).__name__}: {exc}")
        out: dict[str, Any] = {"off_commanded_at_s": t_cmd}
        try:
            out["laser_ma"] = float(self.controller.laser_current_ma())
            out["hv_v"] = float(self.controller.hv_v())
            out["laser_on"] = bool(self.controller.laser_is_on())
            out["hv_on"] = bool(self.controller.hv_is_on())
        except Exception as exc:
            errors.append(f"readback: {type(exc).__name__}: {exc}")
        out["safe_at_s"] = float(self._now())
        out["errors"] = errors
        out["safe"] = (not errors and not out.get("laser_on") and not out.get("hv_on")
                       and out.get("laser_ma", 1.0) <= 0.5 and out.get("hv_v", 1.0) <= 0.25)
        return out

    # -- outputs up and down ------------------------------------------------------------------------
    def bring_up(self, *, check_hv: bool = True) -> None:
        """Refuse with the interlock open; else laser and HV up to their setpoints and read back.
        ``check_hv``: refuse (outputs down again) when the HV read back cannot pull in every switch
        (selftest_analysis.hv_margin_problem); the self-test skips it to diagnose instead."""
        if not self.controller.interlock_closed():
            raise InstrumentError("controller: interlock open; close it before scanning")
        self.controller.bring_up(self.laser_current_ma, self.hv_v, settle_check=self.settle())
        if check_hv and self.pull_in_v is not None:
            problem = hv_margin_problem(float(self.controller.hv_v()), self.pull_in_v, self.spread_v)
            if problem is not None:
                self.bring_down()
                raise InstrumentError(f"controller: {problem}")

    def bring_down(self) -> None:
        try:
            self.controller.bring_down(settle_check=self.settle())
        except Exception:
            # Safety first: at least command the outputs off even when the readback fails.
            for fn in (lambda: self.controller.laser_enable(False), lambda: self.controller.hv_enable(False)):
                try:
                    fn()
                except Exception:
                    pass
            raise


def describe_safe(safe: dict[str, Any]) -> str:
    """One line for the readbacks ``trip()`` returned (stop_reason and error messages)."""
    if safe.get("safe"):
        return (f"laser and HV brought down and read back (laser {safe['laser_ma']:.2f} mA, "
                f"HV {safe['hv_v']:.2f} V)")
    return "SAFE STATE NOT CONFIRMED: " + "; ".join(safe.get("errors") or ["readback out of tolerance"])
