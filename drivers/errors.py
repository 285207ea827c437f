"""The one exception hierarchy of every driver: each error names its device and its command.

Modelled on httpx's ``_exceptions.py``: the tree is documented here, every class carries the
context a log line or an API error body needs, and callers catch as broadly or narrowly as they
mean to. ``exc.device`` is one of ``"fpsa"``, ``"awg"``, ``"digitizer"``, ``"controller"`` (or the
name a driver was given); ``exc.command`` says what was being done (a wire command such as
``ARM`` or ``:FREQ``, a Modbus operation, ``decode`` for a codec error, ``open`` for a channel).
No caller needs to parse a message or guess the device from a module name.

    DeviceError                      base: device, command, detail
    +-- TransportError               the byte channel failed (open, read, write); url
    |   +-- DeviceTimeout            no answer within the timeout after the bounded retries
    |   |                            (also a TimeoutError); timeout_s, attempts
    |   +-- DeviceGone               the device went away or cannot be reached: unplugged USB
    |   |                            (ENODEV), a vanished serial port, a refused TCP connection
    |   |                            (also a ConnectionError)
    |   +-- usbtmc.DeviceIOError     any other USB failure (errno in the detail)
    +-- ProtocolError                bytes that do not follow the wire protocol (codec errors,
    |                                a corrupted segment stream, a link that stays garbled)
    +-- CommandRefused               the device answered "no": FPGA NAK, USB STALL, a SCPI error,
    |                                a Modbus exception response
    +-- DeviceFaulted                latched faults or an open interlock block the command
    +-- InvalidValue                 refused on the host BEFORE anything was sent: a setpoint
    |                                outside its limits, a pattern the FPSA cannot show, a bad
    |                                argument or driver configuration (also a ValueError)
    +-- SettleError                  a readback did not reach its setpoint in time

Per-device names stay importable and are subclasses of these (so ``except DeviceTimeout`` from
this module catches a timeout of any device, and old ``except`` clauses keep working). A timeout is
one class whatever the device (``drivers.usbtmc.DeviceTimeout`` and
``drivers.controller.errors.DeviceTimeout`` are the name ``DeviceTimeout`` of this module, the
device named by ``exc.device``):

    drivers.transport.errors   TransportError, DeviceTimeout            (the classes above)
    drivers.usbtmc             UsbDeviceError, DeviceTimeout, DeviceStall (CommandRefused),
                               DeviceDisconnected (DeviceGone), DeviceIOError,
                               ProtocolError, UsbtmcProtocolError, InvalidArgument (InvalidValue)
    drivers.fpsa.errors        FpsaError, ProtocolError, FramingError, CrcError, LengthError,
                               LinkError, PayloadError, PatternError (InvalidValue),
                               NakError (CommandRefused)
    drivers.controller.errors  ControllerError, LimitError, ConfigError, ProtocolError,
                               DeviceTimeout, DeviceUnreachable (DeviceGone),
                               ModbusExceptionError (CommandRefused) and its code classes,
                               InterlockOpen and DeviceFaulted (DeviceFaulted), SettleError
    drivers.awg                AwgProtocolError, ScpiSyntaxError, BlockError, AwgError
    drivers.digitizer          DigitizerProtocolError, DigitizerError (STALL),
                               DigitizerDataError (ProtocolError)

Pure module: no I/O, importable by codecs, drivers and simulators alike.
"""

from __future__ import annotations

__all__ = [
    "CommandRefused",
    "DeviceError",
    "DeviceFaulted",
    "DeviceGone",
    "DeviceTimeout",
    "InvalidValue",
    "ProtocolError",
    "SettleError",
    "TransportError",
]


class DeviceError(Exception):
    """Base of every driver error: ``device`` and ``command`` name who failed doing what.

    ``detail`` is the human part; ``message`` (if given) replaces the default
    ``"<device>: <command>: <detail>"`` text, so per-device subclasses keep their wording.
    """

    def __init__(self, device: str, command: str, detail: str = "", *, message: str | None = None) -> None:
        self.device = device
        self.command = command
        self.detail = detail
        if message is None:
            message = f"{device}: {command}" + (f": {detail}" if detail else "")
        super().__init__(message)

    def __reduce__(self) -> tuple[object, tuple[type[DeviceError], dict[str, object], str]]:
        # Exceptions cross process boundaries (pytest-xdist, a worker pool); keep the context.
        return _rebuild, (type(self), self.__dict__.copy(), str(self))


def _rebuild(cls: type[DeviceError], state: dict[str, object], message: str) -> DeviceError:
    exc = cls.__new__(cls)  # not __init__: subclasses have their own signatures
    exc.args = (message,)
    exc.__dict__.update(state)
    return exc


class TransportError(DeviceError):
    """The byte channel itself failed (cannot open, read or write); ``url`` where there is one."""

    url: str | None = None

    def __init__(self, device: str, command: str, detail: str = "", *, url: str | None = None,
                 message: str | None = None) -> None:
        self.url = url
        if message is None:
            where = f" ({url})" if url else ""
            message = f"{device}{where}: {command}" + (f": {detail}" if detail else "")
        super().__init__(device, command, detail, message=message)


class DeviceTimeout(TransportError, TimeoutError):
    """The device did not answer ``command`` within the timeout, after all retries."""

    timeout_s: float | None = None
    attempts: int | None = None

    def __init__(self, device: str, command: str, detail: str = "", *, timeout_s: float | None = None,
                 attempts: int | None = None, url: str | None = None, message: str | None = None) -> None:
        self.timeout_s = timeout_s
        self.attempts = attempts
        if message is None and not detail:
            detail = f"no answer to {command}"
            if attempts is not None:
                detail += f" after {attempts} attempt{'s' if attempts != 1 else ''}"
            if timeout_s is not None:
                detail += f" (timeout {timeout_s:g} s each)"
            where = f" ({url})" if url else ""
            message = f"{device}{where}: {detail}"
        super().__init__(device, command, detail, url=url, message=message)


class DeviceGone(TransportError, ConnectionError):
    """The device went away (unplugged, port vanished) or cannot be reached at all."""


class ProtocolError(DeviceError):
    """Bytes that do not follow the device's wire protocol."""


class CommandRefused(DeviceError):
    """The device understood ``command`` and refused it (NAK, STALL, SCPI or Modbus error)."""


class DeviceFaulted(DeviceError):
    """Latched faults (or an open interlock) block ``command``; clear the cause first."""


class InvalidValue(DeviceError, ValueError):
    """A value refused on the host before anything was sent (limits, pattern, argument)."""


class SettleError(DeviceError):
    """A readback did not reach its setpoint within tolerance in the allowed time."""
