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
    +-- ProtocolError                bytes that do not follow the wire protocol: the one codec
    |   |                            error of every device (device as data, ``DEVICE`` per codec)
    |   +-- FramingError             the bytes form no frame (COBS broken, frame too long)
    |   +-- CrcError                 a frame's checksum does not match; seq, cmd as received
    |   +-- LengthError              a length that disagrees with the header or the layout
    |   +-- PayloadError             a well-framed payload with impossible values (an unknown
    |   |                            enum, a register word the map forbids)
    |   +-- LinkError                answers corrupted through every retry
    +-- CommandRefused               the device answered "no": FPGA NAK, USB STALL, a SCPI error,
    |                                a Modbus exception response
    +-- DeviceFaulted                latched faults or an open interlock block the command
    +-- InvalidValue                 refused on the host BEFORE anything was sent: a setpoint
    |                                outside its limits, a pattern the FPSA cannot show, a bad
    |                                argument or driver configuration (also a ValueError)
    +-- SettleError                  a readback did not reach its setpoint in time

A device-specific class exists only where a caller tells it apart (a codec's own ``DEVICE``, a NAK
with its code, a Modbus exception code, a pattern's pixel); each sits in this tree, so
``except ProtocolError`` catches a codec error of any device and ``except DeviceTimeout`` a timeout
of any device (``drivers.usbtmc.DeviceTimeout`` and ``drivers.controller.errors.DeviceTimeout`` are
this module's class, the device named by ``exc.device``):

    drivers.transport.errors   TransportError, DeviceTimeout, DeviceGone  (the classes above)
    drivers.usbtmc             UsbDeviceError, DeviceStall (CommandRefused), DeviceDisconnected
                               (DeviceGone), DeviceIOError, UsbtmcProtocolError (ProtocolError),
                               InvalidArgument (InvalidValue)
    drivers.fpsa.errors        FpsaError, PatternError (InvalidValue), NakError (CommandRefused);
                               its codec raises this module's FramingError ... LinkError
    drivers.controller.errors  ControllerError, LimitError and ConfigError (InvalidValue),
                               DeviceUnreachable (DeviceGone), ModbusExceptionError
                               (CommandRefused) and its code classes, InterlockOpen and
                               DeviceFaulted (DeviceFaulted), SettleError; a register value the
                               map forbids is this module's PayloadError (``bad_value``)
    drivers.awg                AwgProtocolError, ScpiSyntaxError, BlockError (ProtocolError), AwgError
    drivers.digitizer          DigitizerProtocolError (ProtocolError), DigitizerError (STALL),
                               DigitizerDataError (ProtocolError)

Pure module: no I/O, importable by codecs, drivers and simulators alike.
"""

from __future__ import annotations

from typing import ClassVar, TypeVar

__all__ = [
    "detached",
    "CommandRefused",
    "CrcError",
    "DeviceError",
    "DeviceFaulted",
    "DeviceGone",
    "DeviceTimeout",
    "FramingError",
    "InvalidValue",
    "LengthError",
    "LinkError",
    "PayloadError",
    "ProtocolError",
    "SettleError",
    "TransportError",
]

_E = TypeVar("_E", bound=BaseException)


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
    """Bytes that do not follow the device's wire protocol: the one codec error of every device.

    A codec raises it with the message: ``device`` is given or the class's :attr:`DEVICE` (a codec's
    own subclass sets it), ``command`` the command being decoded (``"decode"`` when the bytes did
    not get far enough to say).
    """

    DEVICE: ClassVar[str] = "device"

    def __init__(self, message: str, *, device: str | None = None, command: str = "decode") -> None:
        super().__init__(device or self.DEVICE, command, message, message=message)


class FramingError(ProtocolError):
    """The bytes do not form a frame: the framing (COBS) is broken or a frame overran its maximum."""


class CrcError(ProtocolError):
    """A frame's checksum does not match its bytes; ``seq``/``cmd`` as received (unreliable, may be None)."""

    def __init__(self, message: str, *, device: str | None = None, command: str = "decode",
                 seq: int | None = None, cmd: int | None = None) -> None:
        self.seq = seq
        self.cmd = cmd
        super().__init__(message, device=device, command=command)


class LengthError(ProtocolError):
    """A frame or payload length inconsistent with its header or with the command's layout;
    ``seq``/``cmd`` of the frame when its header was read."""

    def __init__(self, message: str, *, device: str | None = None, command: str = "decode",
                 seq: int | None = None, cmd: int | None = None) -> None:
        self.seq = seq
        self.cmd = cmd
        super().__init__(message, device=device, command=command)


class PayloadError(ProtocolError):
    """A well-framed payload whose values are impossible: an unknown enum value, a register word
    the register map does not allow, a field out of its range."""


class LinkError(ProtocolError):
    """Answers kept arriving corrupted (bad CRC either way) through every retry."""


class CommandRefused(DeviceError):
    """The device understood ``command`` and refused it (NAK, STALL, SCPI or Modbus error)."""


class DeviceFaulted(DeviceError):
    """Latched faults (or an open interlock) block ``command``; clear the cause first."""


class InvalidValue(DeviceError, ValueError):
    """A value refused on the host before anything was sent (limits, pattern, argument)."""


class SettleError(DeviceError):
    """A readback did not reach its setpoint within tolerance in the allowed time."""


def detached(exc: _E) -> _E:
    """``exc`` and the exceptions it was raised from, without their tracebacks: for an exception kept
    past its handler (a job's future, a parser's list of recent errors). A kept traceback keeps every
    frame it passed through with their locals, and in Python 3.11 a frame object that outlives its
    call is linked to its caller's frame, so one kept error pins its whole call stack's frames and
    arrays (a scan's linearization health check: ~5 MB) for as long as it is kept. What a caller reads
    of a failure (type, message, device, command, causes) stays."""
    seen: set[int] = set()
    todo: list[BaseException | None] = [exc]
    while todo:
        cur = todo.pop()
        if cur is None or id(cur) in seen:
            continue
        seen.add(id(cur))
        cur.__traceback__ = None
        todo += [cur.__cause__, cur.__context__]
    return exc
