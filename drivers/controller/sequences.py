"""Power sequences of the laser / TEC / HV controller: bring the outputs up and down in a safe
order, each step commanded AND read back (§4.4.1: the DFB laser's wavelength follows its TEC
temperature; §4.3 and §4.2.6: the MEMS HV).

``bring_up``: TEC settled -> HV on -> laser on; ``bring_down``: laser off -> HV off; on a failure
after the outputs were touched, both are switched off (best effort) before the error propagates.
Waiting uses the injected :attr:`SettleCheck.sleep` (``time.sleep`` in the lab,
``VirtualClock.advance`` on the bench), so this module never decides what time is.
:class:`PowerSequences` is held by :class:`drivers.controller.driver.LaserHvController`, whose
typed register methods, ``limits`` and ``settle_check`` it uses through :class:`ControllerRegisters`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from drivers.controller import protocol as p
from drivers.errors import DeviceError
from drivers.controller.errors import (
    DEVICE,
    ConfigError,
    DeviceFaulted,
    InterlockOpen,
    SettleError,
)


@dataclass(frozen=True)
class SettleCheck:
    """How ``bring_up``/``bring_down`` wait for readbacks.

    ``sleep(dt_s)`` is called between polls; the total wait is the sum of the poll intervals, so
    with ``VirtualClock.advance`` the whole sequence runs in virtual time.
    """

    sleep: Callable[[float], object]
    timeout_s: float = 10.0
    poll_s: float = 0.01
    laser_tol_ma: float = 0.5
    hv_tol_v: float = 0.25
    tec_tol_c: float = 0.1

    def __post_init__(self) -> None:
        for name in ("timeout_s", "poll_s", "laser_tol_ma", "hv_tol_v", "tec_tol_c"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ConfigError(f"{DEVICE}: SettleCheck.{name} must be a finite number > 0, got {v!r}")
        if not callable(self.sleep):
            raise ConfigError(f"{DEVICE}: SettleCheck.sleep must be callable, got {self.sleep!r}")


class ControllerRegisters(Protocol):
    """What the sequences need of the driver: its limits, its default wait, and typed registers."""

    limits: p.Limits
    settle_check: SettleCheck | None

    def status(self) -> p.Status: ...
    def laser_enable(self, on: bool) -> None: ...
    def set_laser_current_ma(self, current_ma: float) -> None: ...
    def laser_current_ma(self) -> float: ...
    def tec_setpoint_c(self) -> float: ...
    def tec_c(self) -> float: ...
    def hv_enable(self, on: bool) -> None: ...
    def set_hv_v(self, voltage_v: float) -> None: ...
    def hv_v(self) -> float: ...
    def interlock_closed(self) -> bool: ...
    def faults(self) -> frozenset[p.Fault]: ...


class PowerSequences:
    """``bring_up`` / ``bring_down`` over the driver's register methods."""

    def __init__(self, regs: ControllerRegisters) -> None:
        self.regs = regs

    def _settle_check(self, settle_check: SettleCheck | None, operation: str) -> SettleCheck:
        sc = settle_check if settle_check is not None else self.regs.settle_check
        if sc is None:
            raise ConfigError(f"{DEVICE}: {operation} needs a SettleCheck (argument or constructor)")
        return sc

    @staticmethod
    def _settle(quantity: str, setpoint: float, read: Callable[[], float], tolerance: float,
                unit: str, sc: SettleCheck) -> float:
        waited_s = 0.0
        while True:
            value = read()
            if abs(value - setpoint) <= tolerance:
                return value
            if waited_s >= sc.timeout_s:
                raise SettleError(quantity, setpoint, value, tolerance, unit, waited_s)
            sc.sleep(sc.poll_s)
            waited_s += sc.poll_s

    def bring_up(self, current_ma: float, hv_v: float, *, settle_check: SettleCheck | None = None) -> p.Status:
        """TEC settled -> HV on at ``hv_v`` -> laser on at ``current_ma``, each read back.

        Both setpoints are limit-checked before anything is sent. On any failure after outputs
        were touched, laser and HV are switched off (best effort) before the error propagates.
        """
        sc = self._settle_check(settle_check, "bring_up")
        current = self.regs.limits.check(p.LASER_CURRENT_SETPOINT, current_ma)
        hv = self.regs.limits.check(p.HV_SETPOINT, hv_v)
        if not self.regs.interlock_closed():
            raise InterlockOpen("bring_up")
        latched = self.regs.faults()
        if latched:
            raise DeviceFaulted("bring_up", latched)
        # The DFB's wavelength follows its temperature: no light before the TEC has settled.
        self._settle("TEC temperature", self.regs.tec_setpoint_c(), self.regs.tec_c, sc.tec_tol_c, "degC", sc)
        try:
            self.regs.set_hv_v(hv)
            self.regs.hv_enable(True)
            self._settle("HV voltage", hv, self.regs.hv_v, sc.hv_tol_v, "V", sc)
            self.regs.set_laser_current_ma(current)
            self.regs.laser_enable(True)
            self._settle("laser current", current, self.regs.laser_current_ma, sc.laser_tol_ma, "mA", sc)
        except DeviceError:
            self._safe_off()
            raise
        return self.regs.status()

    def bring_down(self, *, settle_check: SettleCheck | None = None) -> p.Status:
        """Laser off (current to 0) first, then HV off (voltage to 0); both read back to 0."""
        sc = self._settle_check(settle_check, "bring_down")
        self.regs.laser_enable(False)
        self.regs.set_laser_current_ma(0.0)
        self._settle("laser current", 0.0, self.regs.laser_current_ma, sc.laser_tol_ma, "mA", sc)
        self.regs.hv_enable(False)
        self.regs.set_hv_v(0.0)
        self._settle("HV voltage", 0.0, self.regs.hv_v, sc.hv_tol_v, "V", sc)
        return self.regs.status()

    def _safe_off(self) -> None:
        for fn in (self.regs.laser_enable, self.regs.hv_enable):
            try:
                fn(False)
            except DeviceError:
                pass  # the original error is what the caller needs to see
