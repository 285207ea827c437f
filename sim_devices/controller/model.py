"""The device logic of the simulated laser / TEC / HV controller, without the Modbus server
(§4.4.1, Fig. 4-29: DFB laser current; §4.3 and §4.2.6: the MEMS HV supply; the TEC,
whose set point the laser chip's true temperature may not follow).

:class:`ControllerModel` holds the state behind the register map of ``drivers.controller.protocol``:
readbacks follow their targets with first-order lags on the shared virtual clock (x -> target +
(x - target) exp(-dt / tau), :class:`Dynamics`), out-of-range or refused writes return the Modbus
exception code and change nothing, the interlock and latched faults trip the outputs, and the laser
chip's true temperature adds what the TEC readback cannot show. ``sim_devices.controller.device`` serves
it over Modbus TCP (:class:`~sim_devices.controller.device.ControllerSim`).
"""

from __future__ import annotations

import copy
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field

from drivers.controller import protocol as p
from drivers.controller.errors import LimitError
from drivers.errors import ProtocolError
from sim_devices.clock import VirtualClock


@dataclass(frozen=True)
class Dynamics:
    """First-order time constants of the outputs and the ambient temperature."""

    laser_tau_s: float = 1e-3   # current driver loop
    hv_tau_s: float = 5e-3      # HV amplifier slew into the MEMS electrode capacitance
    tec_tau_s: float = 2.0      # thermal time constant of the laser butterfly on the TEC
    ambient_c: float = 25.0

    def __post_init__(self) -> None:
        for name in ("laser_tau_s", "hv_tau_s", "tec_tau_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"Dynamics.{name} must be finite and > 0, got {v!r}")


@dataclass(frozen=True)
class ControllerSpec:
    """What a simulated controller is: its output ``dynamics``, the hardware limits it enforces on a
    write, and the identity it reports (``model`` name, ``firmware`` (major, minor), register-map
    version; another map version lets tests play an incompatible device)."""

    dynamics: Dynamics = field(default_factory=Dynamics)
    hw_limits: p.Limits = p.HARDWARE_LIMITS
    model: str = "LHV-1550"
    firmware: tuple[int, int] = (1, 0)
    map_version: int = p.MAP_VERSION


@dataclass
class ControllerState:
    """Plain state the bench reads (outputs are the ACTUAL values, not setpoints)."""

    interlock_closed: bool = True
    laser_on: bool = False
    laser_current_ma: float = 0.0
    hv_on: bool = False
    hv_v: float = 0.0
    tec_c: float = 25.0
    laser_setpoint_ma: float = 0.0
    hv_setpoint_v: float = 0.0
    hv_hold_setpoint_v: float = 0.0  # 0 = lines held at the full HV (sim_devices.fpsa.hv_drive)
    tec_setpoint_c: float = 25.0
    faults: set[p.Fault] = field(default_factory=set)
    last_command: int = 0


def _approach(x: float, target: float, dt_s: float, tau_s: float) -> float:
    return target + (x - target) * math.exp(-dt_s / tau_s)


def _bits_to_words(bits: Sequence[bool | int]) -> list[int]:
    # pymodbus' SimDevice packs coil/discrete-input n at bit (n % 16) of word n // 16.
    words = [0] * ((len(bits) + 15) // 16)
    for i, b in enumerate(bits):
        if b:
            words[i // 16] |= 1 << (i % 16)
    return words


class ControllerModel:
    """Device logic without networking (what the firmware would do). Thread-safe."""

    def __init__(
        self,
        clock: VirtualClock,
        *,
        spec: ControllerSpec | None = None,
        tec_drift=None,
    ) -> None:
        """``spec``: the device simulated (default: the LHV-1550 of the register map); ``tec_drift``:
        anything with ``.at(t_s)`` -> the TEC's true temperature drift (C), or None."""
        s = ControllerSpec() if spec is None else spec
        dynamics, hw_limits, model, firmware, map_version = s.dynamics, s.hw_limits, s.model, s.firmware, s.map_version
        self.clock = clock
        self.tec_drift = tec_drift       # anything with .at(t_s) -> C, or None
        self.tec_offset_c = 0.0          # an injected step of the true temperature (fault tec_offset)
        self.map_version = map_version  # another value lets tests play an incompatible device
        self.dynamics = dynamics
        self.hw_limits = hw_limits
        self._model_words = p.encode_value(p.MODEL, model)
        self._firmware_word = p.encode_firmware(*firmware)
        self._lock = threading.RLock()
        self._t0_s = clock.now()
        self._t_last_s = self._t0_s
        self._state = ControllerState(tec_c=dynamics.ambient_c, tec_setpoint_c=dynamics.ambient_c)
        self._causes: set[p.Fault] = set()  # faults whose cause is still present
        self.heartbeat = 0

    # -- time -------------------------------------------------------------------------------
    def _advance(self) -> None:
        now = self.clock.now()
        dt = now - self._t_last_s
        if dt <= 0.0:
            return
        s, d = self._state, self.dynamics
        s.laser_current_ma = _approach(s.laser_current_ma, s.laser_setpoint_ma if s.laser_on else 0.0,
                                       dt, d.laser_tau_s)
        s.hv_v = _approach(s.hv_v, s.hv_setpoint_v if s.hv_on else 0.0, dt, d.hv_tau_s)
        s.tec_c = _approach(s.tec_c, s.tec_setpoint_c, dt, d.tec_tau_s)
        self._t_last_s = now

    @property
    def state(self) -> ControllerState:
        """A snapshot of the state at the clock's current time."""
        with self._lock:
            self._advance()
            snap = copy.copy(self._state)
            snap.faults = set(self._state.faults)
            return snap

    def laser_temperature_c(self) -> float:
        """The laser chip's true temperature: the thermistor's plus the drift and any injected step."""
        with self._lock:
            self._advance()
            now, tec_c, offset_c = self.clock.now(), self._state.tec_c, self.tec_offset_c
        # outside the lock: the Modbus thread never waits for the drift's random draws
        return tec_c + offset_c + (0.0 if self.tec_drift is None else self.tec_drift.at(now))

    # -- bench / fault hooks ----------------------------------------------------------------
    def _trip(self) -> None:
        s = self._state
        s.laser_on = s.hv_on = False
        s.laser_current_ma = 0.0
        s.hv_v = 0.0

    def set_interlock(self, closed: bool) -> None:
        with self._lock:
            self._advance()
            self._state.interlock_closed = bool(closed)
            if not closed:
                self._state.faults.add(p.Fault.INTERLOCK_OPEN)
                self._trip()

    def inject_fault(self, fault: p.Fault) -> None:
        with self._lock:
            self._advance()
            self._state.faults.add(fault)
            self._trip()

    def set_fault_cause(self, fault: p.Fault, present: bool) -> None:
        """A persistent cause (an HV supply that keeps tripping): while present the fault is
        latched, the outputs are off and CLEAR_FAULTS leaves it latched."""
        with self._lock:
            self._advance()
            if present:
                self._causes.add(fault)
                self._state.faults.add(fault)
                self._trip()
            else:
                self._causes.discard(fault)

    # -- register images --------------------------------------------------------------------
    def image(self, table: p.Table) -> list[int] | list[bool]:
        """Current content of ``table`` from address 0 (bits for coil/DI tables)."""
        with self._lock:
            self._advance()
            s = self._state
            if table is p.Table.COIL:
                return [s.laser_on, s.hv_on]
            if table is p.Table.DISCRETE_INPUT:
                settled = abs(s.tec_c - s.tec_setpoint_c) <= p.TEC_SETTLED_BAND_C
                return [s.interlock_closed, s.laser_on, s.hv_on, bool(s.faults), settled]
            if table is p.Table.HOLDING:
                return [
                    *p.encode_value(p.LASER_CURRENT_SETPOINT, s.laser_setpoint_ma),
                    *p.encode_value(p.TEC_SETPOINT, s.tec_setpoint_c),
                    *p.encode_value(p.HV_SETPOINT, s.hv_setpoint_v),
                    s.last_command,
                    *p.encode_value(p.HV_HOLD_SETPOINT, s.hv_hold_setpoint_v),
                ]
            uptime_ms = int((self.clock.now() - self._t0_s) * 1000.0) % (1 << 32)
            return [
                *self._model_words,
                self._firmware_word,
                self.map_version,
                *p.encode_value(p.LASER_CURRENT, _clip(p.LASER_CURRENT, s.laser_current_ma)),
                *p.encode_value(p.TEC_TEMPERATURE, _clip(p.TEC_TEMPERATURE, s.tec_c)),
                *p.encode_value(p.HV_VOLTAGE, _clip(p.HV_VOLTAGE, s.hv_v)),
                p.encode_faults(s.faults),
                *p.encode_value(p.UPTIME_MS, uptime_ms),
                self.heartbeat & 0xFFFF,
            ]

    # -- writes -----------------------------------------------------------------------------
    def write(self, table: p.Table, address: int, values: Sequence[int] | Sequence[bool]) -> p.ExceptionCode | None:
        """Apply a Modbus write; returns the exception code to answer with, or None if accepted.
        Validates everything first, so a refused write changes nothing."""
        with self._lock:
            self._advance()
            if table is p.Table.COIL:
                return self._write_coils(address, [bool(v) for v in values])
            if table is p.Table.HOLDING:
                return self._write_holding(address, [int(v) for v in values])
            return p.ExceptionCode.ILLEGAL_FUNCTION

    def _write_coils(self, address: int, bits: list[bool]) -> p.ExceptionCode | None:
        s = self._state
        targets = {}
        for i, b in enumerate(bits):
            reg = p.register_at(p.Table.COIL, address + i)
            if reg is None:
                return p.ExceptionCode.ILLEGAL_DATA_ADDRESS
            targets[reg.name] = b
        if any(targets.values()) and (not s.interlock_closed or s.faults):
            return p.ExceptionCode.SERVER_DEVICE_FAILURE
        if p.LASER_ENABLE.name in targets:
            s.laser_on = targets[p.LASER_ENABLE.name]
        if p.HV_ENABLE.name in targets:
            s.hv_on = targets[p.HV_ENABLE.name]
        return None

    def _write_holding(self, address: int, words: list[int]) -> p.ExceptionCode | None:
        s = self._state
        updates: list[tuple[p.Register, float | int]] = []
        for i, w in enumerate(words):
            reg = p.register_at(p.Table.HOLDING, address + i)
            if reg is None:
                return p.ExceptionCode.ILLEGAL_DATA_ADDRESS
            try:
                value = p.decode_value(reg, [w])
                if isinstance(value, str):   # text registers are input registers, several words each
                    return p.ExceptionCode.ILLEGAL_DATA_VALUE
                if reg is p.COMMAND:
                    value = p.Command(int(value))   # a U16 at scale 1: already an int
                else:
                    self.hw_limits.check(reg, float(value))
            except (ProtocolError, LimitError, ValueError):
                return p.ExceptionCode.ILLEGAL_DATA_VALUE
            updates.append((reg, value))
        for reg, value in updates:
            if reg is p.LASER_CURRENT_SETPOINT:
                s.laser_setpoint_ma = float(value)
            elif reg is p.TEC_SETPOINT:
                s.tec_setpoint_c = float(value)
            elif reg is p.HV_SETPOINT:
                s.hv_setpoint_v = float(value)
            elif reg is p.HV_HOLD_SETPOINT:
                s.hv_hold_setpoint_v = float(value)
            elif reg is p.COMMAND:
                s.last_command = int(value)
                if value is p.Command.CLEAR_FAULTS:
                    s.faults = {p.Fault.INTERLOCK_OPEN} if not s.interlock_closed else set()
                    s.faults |= self._causes
        return None


def _clip(reg: p.Register, value: float) -> float:
    lo, hi = reg.representable_range()
    return min(max(value, lo), hi)
