"""Typed errors of the FPSA controller link (codec and driver), in the tree of :mod:`drivers.errors`.

The codec raises the shared codec errors of :mod:`drivers.errors` (:class:`~drivers.errors.FramingError`,
``CrcError``, ``LengthError``, ``PayloadError``; the driver ``LinkError``), all
:class:`~drivers.errors.ProtocolError`, and the frame parser raises or reports nothing else, whatever
bytes it is fed. They carry ``device="fpsa"`` (:data:`DEVICE`) and ``command`` = the command byte's
name when the frame got far enough to say it (:func:`error_command`), else ``"decode"``. The FPSA's own
classes are the ones a caller tells apart: :class:`PatternError` (an
:class:`~drivers.errors.InvalidValue`, caught before anything is sent) and :class:`NakError` (a
:class:`~drivers.errors.CommandRefused`: the FPGA refused a command and said why).
"""

from __future__ import annotations

from drivers import errors as _e
from drivers.fpsa.protocol_codes import Cmd

DEVICE = "fpsa"


def error_command(cmd: int | None) -> str:
    """The ``command`` of a codec error: the command byte's name, ``"decode"`` before the header."""
    if cmd is None:
        return "decode"
    try:
        return Cmd(cmd).name
    except ValueError:
        return f"cmd 0x{cmd:02X}"


class FpsaError(_e.DeviceError):
    """Base of every FPSA-specific error (``device`` defaults to ``"fpsa"``)."""

    def __init__(self, message: str, *, device: str = DEVICE, command: str = "decode") -> None:
        super().__init__(device, command, message, message=message)


class PatternError(FpsaError, _e.InvalidValue):
    """A pattern (or single pixel) the hardware cannot show; names the pixel index and row."""

    def __init__(self, message: str, *, index: int | None = None, row: int | None = None,
                 col: int | None = None, device: str = DEVICE, command: str = "UPLOAD_PATTERN") -> None:
        self.index = index
        self.row = row
        self.col = col
        super().__init__(message, device=device, command=command)


class NakError(FpsaError, _e.CommandRefused):
    """The FPGA answered NAK: ``code`` is a :class:`drivers.fpsa.protocol.NakCode`."""

    def __init__(self, device: str, command: str, code: object, detail: int | None) -> None:
        self.code = code
        self.nak_detail = detail
        name = getattr(code, "name", str(code))
        extra = f" (detail {detail})" if detail is not None else ""
        super().__init__(f"{device}: {command} refused with NAK {name}{extra}", device=device, command=command)
