"""Typed errors of the FPSA controller link (codec and driver).

Codec errors derive from :class:`ProtocolError`; the frame parser raises or reports nothing
else, whatever bytes it is fed. Driver-level refusals are :class:`PatternError` (caught before
anything is sent) and :class:`NakError` (the FPGA refused a command and said why).
"""

from __future__ import annotations


class FpsaError(Exception):
    """Base of every FPSA-specific error."""


class ProtocolError(FpsaError):
    """Bytes on the wire that do not form a valid frame or payload."""


class FramingError(ProtocolError):
    """COBS decoding failed or a frame overran the maximum encoded length."""


class CrcError(ProtocolError):
    """Frame CRC-16 mismatch. ``seq``/``cmd`` are as received (unreliable, may be None)."""

    def __init__(self, message: str, *, seq: int | None = None, cmd: int | None = None) -> None:
        self.seq = seq
        self.cmd = cmd
        super().__init__(message)


class LengthError(ProtocolError):
    """Frame or payload length inconsistent with the header or with the command's layout."""

    def __init__(self, message: str, *, seq: int | None = None, cmd: int | None = None) -> None:
        self.seq = seq
        self.cmd = cmd
        super().__init__(message)


class LinkError(ProtocolError):
    """Answers kept arriving corrupted (bad CRC either way) through every retry."""


class PayloadError(ProtocolError):
    """A well-framed payload whose field values are impossible (e.g. an unknown enum value)."""


class PatternError(FpsaError, ValueError):
    """A pattern (or single pixel) the hardware cannot show; names the pixel index and row."""

    def __init__(self, message: str, *, index: int | None = None, row: int | None = None,
                 col: int | None = None) -> None:
        self.index = index
        self.row = row
        self.col = col
        super().__init__(message)


class NakError(FpsaError):
    """The FPGA answered NAK: ``code`` is a :class:`drivers.fpsa.protocol.NakCode`."""

    def __init__(self, device: str, command: str, code: object, detail: int | None) -> None:
        self.device = device
        self.command = command
        self.code = code
        self.detail = detail
        name = getattr(code, "name", str(code))
        extra = f" (detail {detail})" if detail is not None else ""
        super().__init__(f"{device}: {command} refused with NAK {name}{extra}")
