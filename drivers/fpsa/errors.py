"""Typed errors of the FPSA controller link (codec and driver), in the tree of :mod:`drivers.errors`.

Codec errors derive from :class:`ProtocolError`; the frame parser raises or reports nothing
else, whatever bytes it is fed. Codec errors carry ``device="fpsa"`` and ``command`` = the
command byte's name when the frame got far enough to say it, else ``"decode"``. Driver-level
refusals are :class:`PatternError` (an :class:`~drivers.errors.InvalidValue`, caught before
anything is sent) and :class:`NakError` (a :class:`~drivers.errors.CommandRefused`: the FPGA
refused a command and said why).
"""

from __future__ import annotations

from drivers import errors as _e
from drivers.fpsa.protocol_codes import Cmd

DEVICE = "fpsa"


def _cmd_name(cmd: int | None) -> str:
    if cmd is None:
        return "codec"
    try:
        return Cmd(cmd).name
    except ValueError:
        return f"cmd 0x{cmd:02X}"


class FpsaError(_e.DeviceError):
    """Base of every FPSA-specific error (``device`` defaults to ``"fpsa"``)."""

    def __init__(self, message: str, *, device: str = DEVICE, command: str = "codec") -> None:
        super().__init__(device, command, message, message=message)


class ProtocolError(FpsaError, _e.ProtocolError):
    """Bytes on the wire that do not form a valid frame or payload."""


class FramingError(ProtocolError):
    """COBS decoding failed or a frame overran the maximum encoded length."""


class CrcError(ProtocolError):
    """Frame CRC-16 mismatch. ``seq``/``cmd`` are as received (unreliable, may be None)."""

    def __init__(self, message: str, *, seq: int | None = None, cmd: int | None = None) -> None:
        self.seq = seq
        self.cmd = cmd
        super().__init__(message, command=_cmd_name(cmd))


class LengthError(ProtocolError):
    """Frame or payload length inconsistent with the header or with the command's layout."""

    def __init__(self, message: str, *, seq: int | None = None, cmd: int | None = None) -> None:
        self.seq = seq
        self.cmd = cmd
        super().__init__(message, command=_cmd_name(cmd))


class LinkError(ProtocolError):
    """Answers kept arriving corrupted (bad CRC either way) through every retry."""


class PayloadError(ProtocolError):
    """A well-framed payload whose field values are impossible (e.g. an unknown enum value)."""


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
