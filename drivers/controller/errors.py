"""Typed errors of the laser / TEC / HV controller driver.

Every error names the device ("controller"), the register or quantity involved and the offending
value, so a log line alone says what went wrong. The hierarchy lets callers catch broadly
(``ControllerError``, or :class:`drivers.errors.DeviceError` for any device's failure, a timeout
included) or narrowly (``DeviceRefused``, ``DeviceTimeout``, ``InterlockOpen``).
All classes sit in the tree of :mod:`drivers.errors` and carry ``device`` and ``command`` (the
Modbus operation or the setpoint being written). Pure module: no I/O, importable by the simulator
and by the driver alike.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from drivers import errors as _e

if TYPE_CHECKING:
    from drivers.controller.protocol_map import Fault

DEVICE = "controller"


class ControllerError(_e.DeviceError):
    """Base class of every error raised by drivers.controller (``device`` = "controller")."""

    def __init__(self, message: str, *, command: str = "configure", device: str = DEVICE) -> None:
        _e.DeviceError.__init__(self, device, command, message, message=message)


class LimitError(ControllerError, _e.InvalidValue):
    """A setpoint lies outside the allowed range; raised BEFORE anything is sent."""

    def __init__(self, quantity: str, value: float, low: float, high: float, unit: str) -> None:
        self.quantity = quantity
        self.value = value
        self.low = low
        self.high = high
        self.unit = unit
        super().__init__(
            f"{DEVICE}: {quantity} = {value!r} {unit} is outside the allowed range "
            f"[{low:g}, {high:g}] {unit}; nothing was sent", command=f"write {quantity}",
        )


class ConfigError(ControllerError, _e.InvalidValue):
    """Driver configuration (limits, tolerances) is inconsistent."""


def bad_value(what: str, value: object, reason: str) -> _e.PayloadError:
    """A reply or register value that the register map does not allow: the shared
    :class:`drivers.errors.PayloadError` (a ProtocolError) naming the register, the value and why."""
    return _e.PayloadError(f"{DEVICE}: bad {what} = {value!r}: {reason}", device=DEVICE, command=f"decode {what}")


#: No reply after the bounded number of attempts: the one timeout of every device
#: (:class:`drivers.errors.DeviceTimeout`; ``device``, ``command`` = the Modbus operation, ``attempts``).
DeviceTimeout = _e.DeviceTimeout


class DeviceUnreachable(ControllerError, _e.DeviceGone):
    """The TCP connection to the controller could not be opened."""

    def __init__(self, device: str, host: str, port: int, operation: str) -> None:
        self.host = host
        self.port = port
        self.operation = operation
        self.url = f"modbus+tcp://{host}:{port}"
        super().__init__(f"{device}: cannot connect to {host}:{port} for {operation}",
                         command=operation, device=device)


class ModbusExceptionError(ControllerError, _e.CommandRefused):
    """The device answered with a Modbus exception response (function code | 0x80)."""

    #: Modbus exception code this class stands for (None: any code not mapped to a subclass)
    code: int | None = None

    def __init__(self, operation: str, register: str, value: object, code: int) -> None:
        self.operation = operation
        self.register = register
        self.value = value
        self.exception_code = code
        super().__init__(
            f"{DEVICE}: {operation} of {register}"
            + ("" if value is None else f" = {value!r}")
            + f" answered with Modbus exception {code} ({_EXC_NAMES.get(code, 'unknown')})",
            command=operation,
        )


class IllegalFunction(ModbusExceptionError):
    code = 1


class IllegalAddress(ModbusExceptionError):
    code = 2


class DeviceRefused(ModbusExceptionError):
    """ILLEGAL DATA VALUE (3): the device's own hardware limits refused the value."""

    code = 3


class DeviceFailure(ModbusExceptionError):
    """SERVER DEVICE FAILURE (4): e.g. an enable refused because the interlock is open."""

    code = 4


class DeviceBusy(ModbusExceptionError):
    code = 6


class InterlockOpen(ControllerError, _e.DeviceFaulted):
    """The safety interlock is open, so the laser / HV cannot be (or are no longer) on."""

    def __init__(self, operation: str) -> None:
        self.operation = operation
        super().__init__(f"{DEVICE}: interlock is open; {operation} not possible", command=operation)


class DeviceFaulted(ControllerError, _e.DeviceFaulted):
    """Latched faults prevent the operation."""

    def __init__(self, operation: str, faults: frozenset[Fault]) -> None:
        self.operation = operation
        self.faults = faults
        names = ", ".join(sorted(f.name for f in faults)) or "none"
        super().__init__(f"{DEVICE}: {operation} blocked by latched faults: {names}", command=operation)


class SettleError(ControllerError, _e.SettleError):
    """A readback did not reach its setpoint within tolerance in the allowed time."""

    def __init__(
        self, quantity: str, setpoint: float, readback: float, tolerance: float, unit: str,
        waited_s: float,
    ) -> None:
        self.quantity = quantity
        self.setpoint = setpoint
        self.readback = readback
        self.tolerance = tolerance
        self.unit = unit
        self.waited_s = waited_s
        super().__init__(
            f"{DEVICE}: {quantity} readback {readback:g} {unit} did not reach setpoint "
            f"{setpoint:g} {unit} (tolerance +/-{tolerance:g} {unit}) within {waited_s:g} s",
            command=f"settle {quantity}",
        )


_EXC_NAMES = {
    1: "ILLEGAL FUNCTION",
    2: "ILLEGAL DATA ADDRESS",
    3: "ILLEGAL DATA VALUE",
    4: "SERVER DEVICE FAILURE",
    5: "ACKNOWLEDGE",
    6: "SERVER DEVICE BUSY",
    8: "MEMORY PARITY ERROR",
    10: "GATEWAY PATH UNAVAILABLE",
    11: "GATEWAY TARGET DEVICE FAILED TO RESPOND",
}

_BY_CODE = {cls.code: cls for cls in (IllegalFunction, IllegalAddress, DeviceRefused, DeviceFailure, DeviceBusy)}


def modbus_exception(operation: str, register: str, value: object, code: int) -> ModbusExceptionError:
    """The typed error for Modbus exception ``code`` (generic class for unmapped codes)."""
    return _BY_CODE.get(code, ModbusExceptionError)(operation, register, value, code)
