"""USBTMC (USB488) bulk framing and the USB error types shared by the AWG and digitizer drivers.

§4.4.1 of the dissertation: the arbitrary waveform generator that drives the laser with the
pre-distorted chirp and the ADC that samples the beat are both on the PC's USB bus. The AWG speaks
USBTMC (USB Test & Measurement Class, rev 1.0, USB488 subclass): every bulk transfer begins with a
12-byte header

    byte 0     MsgID   1 = DEV_DEP_MSG_OUT, 2 = REQUEST_DEV_DEP_MSG_IN (host->device)
                       2 = DEV_DEP_MSG_IN (device->host)
    byte 1     bTag    1..255, incremented per transfer by the host
    byte 2     ~bTag   bitwise inverse of bTag (a cheap sanity check, also what resyncs a stream)
    byte 3     0x00
    bytes 4-7  TransferSize, u32 little endian (message bytes in this transfer / max wanted)
    byte 8     bmTransferAttributes (bit0 EOM for MSG_OUT/MSG_IN, bit1 TermCharEnabled for REQUEST)
    byte 9     TermChar (REQUEST only)
    bytes 10-11 0x00 0x00

followed (MSG_OUT, MSG_IN) by TransferSize message bytes padded with zeros to a multiple of 4.

This module is PURE (no I/O). Decoders raise only ``UsbtmcProtocolError`` (a
:class:`drivers.errors.ProtocolError`).
Golden byte vectors are in docs/protocols/awg.md.

The typed USB driver errors (``DeviceTimeout`` etc.) live here too because both USB drivers raise
them and both map pyusb's ``USBError`` the same way (errno ETIMEDOUT/EPIPE/ENODEV). They are
subclasses of the shared tree in :mod:`drivers.errors` (``DeviceTimeout`` IS its DeviceTimeout,
``DeviceStall`` of CommandRefused, ``DeviceDisconnected`` of DeviceGone, codec errors of its
ProtocolError), so every one carries ``device`` and ``command``.
"""

from __future__ import annotations

import errno as _errno
import struct
from dataclasses import dataclass

from drivers import errors as _e

# ----------------------------------------------------------------------------------------- errors


class UsbtmcProtocolError(_e.ProtocolError):
    """A USBTMC header or message that cannot be decoded (the AWG is the USBTMC device)."""

    DEVICE = "awg"


class UsbDeviceError(_e.DeviceError):
    """Base of the typed errors a USB driver raises; names the device and the command."""

    def __init__(self, device: str, command: str, detail: str = "") -> None:
        msg = f"{device}: {command!r}"
        if detail:
            msg += f": {detail}"
        _e.DeviceError.__init__(self, device, command, detail, message=msg)


#: The device did not answer within the timeout after the bounded retries: the one timeout of every
#: device (:class:`drivers.errors.DeviceTimeout`, the device named as data).
DeviceTimeout = _e.DeviceTimeout


class DeviceStall(UsbDeviceError, _e.CommandRefused):
    """The device stalled an endpoint (USB STALL, errno EPIPE): it refused the request."""


class DeviceDisconnected(UsbDeviceError, _e.DeviceGone):
    """The device went away (errno ENODEV / ENXIO / EIO)."""


class DeviceIOError(UsbDeviceError, _e.TransportError):
    """Any other USB failure, with the errno in the detail."""


class InvalidArgument(_e.InvalidValue):
    """A value passed to a driver method is outside what the instrument accepts (names it).

    ``InvalidArgument(device, command, message)``; nothing was sent.
    """

    def __init__(self, device: str, command: str, message: str) -> None:
        super().__init__(device, command, message, message=message)


def classify_usb_error(exc: BaseException, device: str, command: str) -> _e.DeviceError:
    """Map a pyusb ``USBError`` to the typed driver error (does not raise)."""
    # pyusb sets errno for libusb1 errors; USBTimeoutError carries ETIMEDOUT
    code = getattr(exc, "errno", None)
    name = type(exc).__name__
    if name == "USBTimeoutError" or code == _errno.ETIMEDOUT:
        return DeviceTimeout(device, command, "USB transfer timed out")
    if code == _errno.EPIPE:
        return DeviceStall(device, command, "endpoint stalled (EPIPE)")
    if code in (_errno.ENODEV, _errno.ENXIO, _errno.ESHUTDOWN):
        return DeviceDisconnected(device, command, "device disconnected (ENODEV)")
    return DeviceIOError(device, command, f"USB error errno={code}: {exc}")


# ------------------------------------------------------------------------------------- framing

MSG_DEV_DEP_MSG_OUT = 1
MSG_REQUEST_DEV_DEP_MSG_IN = 2
MSG_DEV_DEP_MSG_IN = 2  # same id, opposite direction
HEADER_LEN = 12
ATTR_EOM = 0x01
ATTR_TERMCHAR_ENABLED = 0x02
#: Largest TransferSize we accept in a header: bounds memory and makes garbage headers implausible
MAX_TRANSFER_SIZE = 64 * 1024 * 1024

_HDR = struct.Struct("<BBBBIBBBB")

# USBTMC class-specific control requests (bmRequestType 0xA1: class, interface, IN)
REQTYPE_CLASS_INTERFACE_IN = 0xA1
REQ_INITIATE_CLEAR = 5
REQ_CHECK_CLEAR_STATUS = 6
STATUS_SUCCESS = 0x01
STATUS_PENDING = 0x02


@dataclass(frozen=True)
class UsbtmcHeader:
    msg_id: int
    btag: int
    transfer_size: int
    attributes: int = 0
    term_char: int = 0

    @property
    def eom(self) -> bool:
        return bool(self.attributes & ATTR_EOM)


def _check_btag(btag: int) -> None:
    if not 1 <= btag <= 255:
        raise UsbtmcProtocolError(f"bTag must be 1..255, got {btag}")


def next_btag(btag: int) -> int:
    """bTag sequence 1..255, skipping 0 as the spec requires."""
    return 1 if btag >= 255 else btag + 1


def padded_len(n: int) -> int:
    return (n + 3) & ~3


def encode_dev_dep_msg_out(btag: int, message: bytes, eom: bool = True) -> bytes:
    """One DEV_DEP_MSG_OUT transfer: header + message + zero padding to 4 bytes."""
    _check_btag(btag)
    n = len(message)
    if n > MAX_TRANSFER_SIZE:
        raise UsbtmcProtocolError(f"message chunk of {n} bytes exceeds {MAX_TRANSFER_SIZE}")
    hdr = _HDR.pack(MSG_DEV_DEP_MSG_OUT, btag, btag ^ 0xFF, 0, n, ATTR_EOM if eom else 0, 0, 0, 0)
    return hdr + bytes(message) + b"\x00" * (padded_len(n) - n)


def encode_request_dev_dep_msg_in(btag: int, max_size: int, term_char: int | None = None) -> bytes:
    """REQUEST_DEV_DEP_MSG_IN: asks the device to queue up to ``max_size`` bytes on bulk-IN."""
    _check_btag(btag)
    if not 1 <= max_size <= MAX_TRANSFER_SIZE:
        raise UsbtmcProtocolError(f"REQUEST_DEV_DEP_MSG_IN max_size {max_size} out of range")
    attr = ATTR_TERMCHAR_ENABLED if term_char is not None else 0
    return _HDR.pack(MSG_REQUEST_DEV_DEP_MSG_IN, btag, btag ^ 0xFF, 0, max_size, attr,
                     term_char or 0, 0, 0)


def encode_dev_dep_msg_in(btag: int, message: bytes, eom: bool = True) -> bytes:
    """DEV_DEP_MSG_IN (device side): header + message + padding."""
    _check_btag(btag)
    n = len(message)
    hdr = _HDR.pack(MSG_DEV_DEP_MSG_IN, btag, btag ^ 0xFF, 0, n, ATTR_EOM if eom else 0, 0, 0, 0)
    return hdr + bytes(message) + b"\x00" * (padded_len(n) - n)


def decode_header(data: bytes | memoryview) -> UsbtmcHeader:
    """Decode and validate the 12-byte header at the start of ``data``."""
    if len(data) < HEADER_LEN:
        raise UsbtmcProtocolError(f"USBTMC header needs {HEADER_LEN} bytes, got {len(data)}")
    msg_id, btag, inv, r0, size, attr, term, r1, r2 = _HDR.unpack_from(data, 0)
    if msg_id not in (MSG_DEV_DEP_MSG_OUT, MSG_REQUEST_DEV_DEP_MSG_IN):
        raise UsbtmcProtocolError(f"unsupported USBTMC MsgID {msg_id}")
    if btag == 0 or inv != btag ^ 0xFF:
        raise UsbtmcProtocolError(f"bTag {btag} / ~bTag {inv} mismatch")
    if r0 != 0 or r1 != 0 or r2 != 0:
        raise UsbtmcProtocolError("USBTMC header reserved bytes not zero")
    if size > MAX_TRANSFER_SIZE:
        raise UsbtmcProtocolError(f"TransferSize {size} exceeds {MAX_TRANSFER_SIZE}")
    return UsbtmcHeader(msg_id, btag, size, attr, term)


def decode_dev_dep_msg_in(transfer: bytes | memoryview, expected_btag: int) -> tuple[bytes, bool]:
    """Host side: decode one bulk-IN transfer -> (message bytes, EOM)."""
    hdr = decode_header(transfer)
    if hdr.msg_id != MSG_DEV_DEP_MSG_IN:
        raise UsbtmcProtocolError(f"expected DEV_DEP_MSG_IN, got MsgID {hdr.msg_id}")
    if hdr.btag != expected_btag:
        raise UsbtmcProtocolError(f"bTag {hdr.btag} does not answer request bTag {expected_btag}")
    end = HEADER_LEN + hdr.transfer_size
    if len(transfer) < end:
        raise UsbtmcProtocolError(
            f"DEV_DEP_MSG_IN announces {hdr.transfer_size} bytes, transfer holds {len(transfer) - HEADER_LEN}")
    return bytes(transfer[HEADER_LEN:end]), hdr.eom


def is_plausible_header(buf: bytes | bytearray, i: int = 0) -> bool:
    """True when a valid host->device header starts at ``buf[i]`` (used to reason about resync)."""
    try:
        decode_header(memoryview(buf)[i:i + HEADER_LEN])
    except UsbtmcProtocolError:
        return False
    return True


class UsbtmcOutParser:
    """Device-side parser of the host's bulk-OUT byte stream.

    ``feed(bytes)`` returns complete ``(header, payload)`` pairs. On bytes that cannot be a header
    it drops one byte and scans forward to the next plausible header (MsgID/bTag/~bTag/reserved
    all valid), so a glitch costs at most the damaged message. Errors seen while resyncing are
    counted in ``dropped_bytes`` rather than raised: a stream parser must keep going.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self.dropped_bytes = 0

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[UsbtmcHeader, bytes]]:
        self._buf += data
        out: list[tuple[UsbtmcHeader, bytes]] = []
        buf = self._buf
        pos = 0
        while len(buf) - pos >= HEADER_LEN:
            try:
                hdr = decode_header(memoryview(buf)[pos:pos + HEADER_LEN])
            except UsbtmcProtocolError:
                pos += 1
                self.dropped_bytes += 1
                continue
            if hdr.msg_id == MSG_REQUEST_DEV_DEP_MSG_IN:
                out.append((hdr, b""))
                pos += HEADER_LEN
                continue
            end = pos + HEADER_LEN + padded_len(hdr.transfer_size)
            if len(buf) < end:
                break
            out.append((hdr, bytes(buf[pos + HEADER_LEN:pos + HEADER_LEN + hdr.transfer_size])))
            pos = end
        del buf[:pos]
        return out

    def reset(self) -> None:
        self._buf.clear()
