"""AWG wire codec: SCPI text and IEEE-488.2 definite-length blocks carried in USBTMC messages.

§4.4.1: the DFB laser is frequency-modulated by the pre-distorted waveform (iterative-learning
pre-distortion, §2.2, Fig. 2-3) played by an arbitrary waveform generator, one waveform period per
external trigger from the FPGA that steps the FPSA (burst mode). This module is the PURE codec for
that instrument: command encoders, the device-side SCPI message parser, reply parsers, and the
normalized-sample <-> int16 DAC code conversion. The USBTMC header framing is in drivers/usbtmc.py.
Parsers raise only ``AwgProtocolError`` subclasses. Dialect and golden bytes: docs/protocols/awg.md.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np

from drivers.errors import ProtocolError
from drivers.usbtmc import InvalidArgument

#: USB IDs of the simulated AWG (pid.codes test VID). The lab configuration names the real ones.
AWG_VID = 0x1209
AWG_PID = 0xA901
#: Bulk endpoints of the USBTMC interface
AWG_EP_OUT = 0x01
AWG_EP_IN = 0x82

#: DAC full scale: code +32767 -> offset + amplitude, -32767 -> offset - amplitude (symmetric;
#: -32768 is accepted on the wire but never produced by the encoder)
CODE_FULL_SCALE = 32767


class AwgProtocolError(ProtocolError):
    """AWG bytes (SCPI text, block, reply) that cannot be decoded."""

    DEVICE = "awg"


class ScpiSyntaxError(AwgProtocolError):
    """A SCPI message that is not well formed."""


class BlockError(AwgProtocolError):
    """A malformed IEEE-488.2 definite-length block."""


# ------------------------------------------------------------------------- IEEE-488.2 block


def encode_block(payload: bytes) -> bytes:
    """``#<n><len><payload>``: n = number of decimal digits of len (1..9)."""
    length = str(len(payload))
    if len(length) > 9:
        raise BlockError(f"block of {len(payload)} bytes too long for a definite-length header")
    return b"#" + str(len(length)).encode() + length.encode() + bytes(payload)


def decode_block(data: bytes | memoryview, pos: int = 0) -> tuple[bytes, int]:
    """Decode the block starting at ``data[pos]``; returns (payload, index just past it)."""
    view = memoryview(data)
    if pos >= len(view) or view[pos] != ord("#"):
        raise BlockError(f"block must start with '#', at offset {pos}")
    if pos + 1 >= len(view):
        raise BlockError("block truncated after '#'")
    nd = view[pos + 1] - ord("0")
    if not 1 <= nd <= 9:
        # '#0' (indefinite length) is legal IEEE-488.2 but this instrument does not accept it
        raise BlockError(f"block digit count must be 1..9, got {chr(view[pos + 1])!r}")
    digits = bytes(view[pos + 2:pos + 2 + nd])
    if len(digits) != nd or not digits.isdigit():
        raise BlockError(f"block length field {digits!r} is not {nd} decimal digits")
    n = int(digits)
    start = pos + 2 + nd
    if start + n > len(view):
        raise BlockError(f"block announces {n} bytes, only {len(view) - start} present")
    return bytes(view[start:start + n]), start + n


# ------------------------------------------------------------------- samples <-> DAC codes


def codes_from_normalized(samples: np.ndarray) -> np.ndarray:
    """Normalized samples in [-1, 1] -> int16 codes (round to nearest)."""
    s = np.asarray(samples, dtype=np.float64)
    if s.ndim != 1:
        raise InvalidArgument("awg", "encode waveform", f"awg: waveform must be 1-D, got shape {s.shape}")
    if s.size and (not np.all(np.isfinite(s)) or np.max(np.abs(s)) > 1.0):
        raise InvalidArgument("awg", "encode waveform", "awg: waveform samples must be finite and within [-1, 1]")
    return np.rint(s * CODE_FULL_SCALE).astype(np.int16)


def volts_from_codes(codes: np.ndarray, amplitude_v: float, offset_v: float) -> np.ndarray:
    """DAC output in volts for int16 codes (the instrument's transfer function)."""
    return offset_v + amplitude_v * (np.asarray(codes, dtype=np.float64) / CODE_FULL_SCALE)


def encode_codes(codes: np.ndarray) -> bytes:
    """int16 codes -> little-endian bytes (the block payload)."""
    return np.ascontiguousarray(codes, dtype="<i2").tobytes()


def decode_codes(payload: bytes) -> np.ndarray:
    if len(payload) % 2:
        raise BlockError(f"waveform block of {len(payload)} bytes is not whole int16 samples")
    return np.frombuffer(payload, dtype="<i2").astype(np.int16)


# ----------------------------------------------------------------------- command encoders


def _num(x: float) -> str:
    if not math.isfinite(x):
        raise InvalidArgument("awg", "encode SCPI", f"awg: SCPI numeric argument must be finite, got {x!r}")
    return repr(float(x))


def cmd_idn() -> bytes:
    return b"*IDN?"


def cmd_rst() -> bytes:
    return b"*RST"


def cmd_cls() -> bytes:
    return b"*CLS"


def cmd_err() -> bytes:
    return b"SYST:ERR?"


def cmd_opc() -> bytes:
    return b"*OPC?"


def cmd_sample_rate(hz: float) -> bytes:
    return f"SOUR:FREQ:SAMP {_num(hz)}".encode()


def cmd_amplitude(v: float) -> bytes:
    return f"SOUR:VOLT {_num(v)}".encode()


def cmd_offset(v: float) -> bytes:
    return f"SOUR:VOLT:OFFS {_num(v)}".encode()


def cmd_trigger_source(external: bool) -> bytes:
    return b"TRIG:SOUR EXT" if external else b"TRIG:SOUR IMM"


def cmd_output(on: bool) -> bytes:
    return b"OUTP ON" if on else b"OUTP OFF"


def cmd_upload(codes: np.ndarray) -> bytes:
    return b"SOUR:DATA:ARB " + encode_block(encode_codes(codes))


# ---------------------------------------------------------------- device-side SCPI parser

#: Long keyword forms accepted besides the short (canonical) forms
_LONG = {
    "SOURCE": "SOUR", "FREQUENCY": "FREQ", "SAMPLE": "SAMP", "VOLTAGE": "VOLT",
    "OFFSET": "OFFS", "TRIGGER": "TRIG", "OUTPUT": "OUTP", "SYSTEM": "SYST", "ERROR": "ERR",
    "POINTS": "POIN", "ARBITRARY": "ARB",
}
_HEADER_RE = re.compile(rb"^(\*[A-Za-z]+\??|:?[A-Za-z][A-Za-z0-9]*(?::[A-Za-z][A-Za-z0-9]*)*\??)")


@dataclass(frozen=True)
class ScpiCommand:
    """One program message unit: canonical header (short form, upper case, no '?'), query flag,
    arguments (text ones stripped, a block argument as bytes)."""

    header: str
    query: bool
    args: tuple[str | bytes, ...] = field(default_factory=tuple)


def _canonical(header: str) -> str:
    if header.startswith("*"):
        return header.upper()
    parts = header.lstrip(":").upper().split(":")
    return ":".join(_LONG.get(p, p) for p in parts)


def parse_message(message: bytes) -> list[ScpiCommand]:
    """Split a program message into commands (``;`` separated, ``\\n`` terminated).

    A definite-length block argument is consumed by length, so its bytes may contain ``;`` or
    newlines. Raises ``ScpiSyntaxError`` / ``BlockError`` on malformed input.
    """
    view = memoryview(message)
    n = len(view)
    pos = 0
    out: list[ScpiCommand] = []
    while pos < n:
        # skip separators / whitespace between units
        while pos < n and view[pos] in b" \t\r\n;":
            pos += 1
        if pos >= n:
            break
        m = _HEADER_RE.match(bytes(view[pos:pos + 64]))
        if m is None:
            raise ScpiSyntaxError(f"no SCPI header at offset {pos}: {bytes(view[pos:pos + 16])!r}")
        raw = m.group(1).decode("ascii")
        pos += len(m.group(1))
        query = raw.endswith("?")
        header = _canonical(raw.rstrip("?"))
        args: list[str | bytes] = []
        if pos < n and view[pos] not in b" \t;\r\n":
            raise ScpiSyntaxError(f"unexpected byte {bytes(view[pos:pos + 1])!r} after header {raw!r}")
        while pos < n and view[pos] in b" \t":
            pos += 1
        if pos < n and view[pos] == ord("#"):
            payload, pos = decode_block(view, pos)
            args.append(payload)
        elif pos < n and view[pos] not in b";\r\n":
            end = pos
            while end < n and view[end] not in b";\r\n":
                end += 1
            text = bytes(view[pos:end])
            try:
                decoded = text.decode("ascii")
            except UnicodeDecodeError as exc:
                raise ScpiSyntaxError(f"non-ASCII argument to {raw!r}") from exc
            args.extend(a.strip() for a in decoded.split(","))
            pos = end
        while pos < n and view[pos] in b" \t\r\n":
            pos += 1
        if pos < n and view[pos] != ord(";"):
            raise ScpiSyntaxError(f"unexpected data after {raw!r} at offset {pos}")
        out.append(ScpiCommand(header, query, tuple(args)))
    return out


# --------------------------------------------------------------------------- reply parsers


@dataclass(frozen=True)
class Identity:
    manufacturer: str
    model: str
    serial: str
    firmware: str


def parse_idn(reply: bytes) -> Identity:
    try:
        text = reply.decode("ascii").strip()
    except UnicodeDecodeError as exc:
        raise AwgProtocolError(f"*IDN? reply is not ASCII: {reply[:32]!r}") from exc
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 4:
        raise AwgProtocolError(f"*IDN? reply must have 4 comma-separated fields: {text!r}")
    return Identity(*parts)


_ERR_RE = re.compile(r'^([+-]?\d+)\s*,\s*"(.*)"$', re.S)


def parse_error(reply: bytes) -> tuple[int, str]:
    """``SYST:ERR?`` reply ``-222,"Data out of range;SOUR:VOLT 99.0"`` -> (-222, text)."""
    try:
        text = reply.decode("ascii").strip()
    except UnicodeDecodeError as exc:
        raise AwgProtocolError(f"SYST:ERR? reply is not ASCII: {reply[:32]!r}") from exc
    m = _ERR_RE.match(text)
    if m is None:
        raise AwgProtocolError(f"SYST:ERR? reply not '<code>,\"<text>\"': {text!r}")
    return int(m.group(1)), m.group(2)


def parse_float(reply: bytes) -> float:
    try:
        return float(reply.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError) as exc:
        raise AwgProtocolError(f"expected a number, got {reply[:32]!r}") from exc


def parse_int(reply: bytes) -> int:
    try:
        return int(reply.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError) as exc:
        raise AwgProtocolError(f"expected an integer, got {reply[:32]!r}") from exc


def format_error(code: int, text: str) -> bytes:
    return f'{code},"{text}"'.encode("ascii", "replace")
