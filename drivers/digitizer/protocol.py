"""Digitizer wire codec: vendor control requests and the framed segment stream on bulk-IN.

§4.4.1: the photodetector's beat signal is sampled by the ADC and sent to the PC; one record
(segment) per external trigger, i.e. per chirp at one FPSA pixel. Optional channels: the auxiliary
MZI used for chirp linearization (§2.2, Fig. 2-3) and I/Q beat (two ADC channels) instead of a single
real beat channel.

Commands are USB vendor control transfers on endpoint 0 (bmRequestType 0x40 OUT / 0xC0 IN); an
invalid request or value makes the device STALL the control pipe (pyusb raises USBError EPIPE), and
``GET_STATUS`` reports the code of the last refused request. Sample data flow on bulk-IN endpoint
0x81 after ``READ_SEGMENTS(first, count)``: every segment is one 32-byte header followed by its
payload (channel-major: all samples of channel 0, then channel 1, ...; little-endian int8/int16):

    off size field
      0   4  magic b"DGSG"
      4   1  version (1)
      5   1  bits per sample (8 | 16)
      6   1  channel mask (bit0 beat, bit1 beat_i, bit2 beat_q, bit3 mzi, bit4 tap, bit5 mzi_q)
      7   1  overrange flags, bit i = i-th channel present in the mask (ascending bit order)
      8   4  segment index (u32)
     12   4  samples per channel (u32)
     16   8  trigger timestamp (u64, ns since bench/device power-up)
     24   4  crc32 of the payload (zlib.crc32)
     28   4  crc32 of header bytes 0..27 (makes resync after garbage reliable)

Channel ``tap`` (bit 4, added for the FPSA self-test; older masks are unchanged) is the monitor
photodiode on the light leaving the FPSA chip: a DC level proportional to the total emitted power.
Channel ``mzi_q`` (bit 5, added for phase-noise compensation at any range) is the monitor
MZI's quadrature output (a 90-degree hybrid or 3x3 coupler): only together with ``mzi``.

All integers little endian. This module is PURE; parsers raise only ``DigitizerProtocolError``.
Golden bytes: docs/protocols/digitizer.md. Parts: the ids, request codes, channel bits and sample
formats are ``protocol_format.py``, the segment headers one by one and a read's worth as columns, and
the crc32 fields of a batch, ``protocol_headers.py`` (both re-exported here); this module holds the
control payloads and the segment stream.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass

import numpy as np

from drivers.digitizer.protocol_format import (
    ALL_CHANNELS_MASK,
    CHANNEL_BITS,
    DIGITIZER_PID,
    DIGITIZER_VID,
    EP_DATA_IN,
    HEADER,
    HEADER_LEN,
    MAGIC,
    REQTYPE_IN,
    REQTYPE_OUT,
    VERSION,
    DigitizerProtocolError,
    Req,
    State,
    bytes_per_sample,
    channel_mask,
    channels_of,
    overrange_flags,
    sample_dtype,
    segment_bytes,
    segment_dtype,
    validate_mask,
)
from drivers.digitizer.protocol_headers import (
    HEADER_CRC_SPAN,
    SegmentHeader,
    SegmentHeaders,
    header_column,
    header_crc32s,
    payload_crc32s,
)


# ---------------------------------------------------------------------- control payloads


def enc_u32(x: int) -> bytes:
    if not 0 <= x <= 0xFFFFFFFF:
        raise DigitizerProtocolError(f"value {x} does not fit u32")
    return struct.pack("<I", x)


def enc_u64(x: int) -> bytes:
    if not 0 <= x <= 0xFFFFFFFFFFFFFFFF:
        raise DigitizerProtocolError(f"value {x} does not fit u64")
    return struct.pack("<Q", x)


def dec_u32(data: bytes) -> int:
    if len(data) != 4:
        raise DigitizerProtocolError(f"expected 4-byte u32, got {len(data)} bytes")
    return struct.unpack("<I", data)[0]


def dec_u64(data: bytes) -> int:
    if len(data) != 8:
        raise DigitizerProtocolError(f"expected 8-byte u64, got {len(data)} bytes")
    return struct.unpack("<Q", data)[0]


def enc_read_segments(first: int, count: int) -> bytes:
    return enc_u32(first) + enc_u32(count)


def dec_read_segments(data: bytes) -> tuple[int, int]:
    if len(data) != 8:
        raise DigitizerProtocolError(f"READ_SEGMENTS needs 8 bytes, got {len(data)}")
    return struct.unpack("<II", data)


_STATUS = struct.Struct("<BBHIII")   # state, last_refused_request, reserved, captured, overrange, read_pos


@dataclass(frozen=True)
class Status:
    state: State
    segments_captured: int
    overrange_count: int
    last_refused_request: int = 0  # bRequest of the last stalled request, 0 = none
    segments_sent: int = 0


def encode_status(s: Status) -> bytes:
    return _STATUS.pack(int(s.state), s.last_refused_request, 0, s.segments_captured,
                        s.overrange_count, s.segments_sent)


def decode_status(data: bytes) -> Status:
    if len(data) != _STATUS.size:
        raise DigitizerProtocolError(f"status must be {_STATUS.size} bytes, got {len(data)}")
    st, refused, _r, cap, ovr, sent = _STATUS.unpack(data)
    try:
        state = State(st)
    except ValueError:
        raise DigitizerProtocolError(f"unknown digitizer state {st}") from None
    return Status(state, cap, ovr, refused, sent)


# rate Hz, record length, segments, range mV, mask, format bits, resolution bits, reserved, bandwidth Hz
_CONFIG = struct.Struct("<QIIIBBBBQ")
CONFIG_LEN = _CONFIG.size  # 32
#: Lowest resolution the ADC quantizes to; the highest is the sample format (8 or 16 bits).
MIN_RESOLUTION_BITS = 8
#: Highest anti-alias corner SET_BANDWIDTH accepts (the analog front end's own limit, Hz)
MAX_BANDWIDTH_HZ = 5_000_000_000


def check_resolution(resolution_bits: int, format_bits: int) -> None:
    """A resolution the format can carry: 8 <= resolution <= format bits (DigitizerProtocolError)."""
    bytes_per_sample(format_bits)
    if not MIN_RESOLUTION_BITS <= resolution_bits <= format_bits:
        raise DigitizerProtocolError(f"resolution must be {MIN_RESOLUTION_BITS}..{format_bits} bits for "
                                     f"{format_bits}-bit samples, got {resolution_bits}")


@dataclass(frozen=True)
class Config:
    """The digitizer's settings as GET_CONFIG reports them.

    ``bits`` is the sample format (8 or 16 bits per stored sample); ``resolution_bits`` the ADC
    resolution the samples are quantized to (0 when constructing = same as ``bits``): a 12-bit
    record in the 16-bit format has codes that are multiples of 2**(16 - 12). ``bandwidth_hz`` is
    the anti-alias low-pass corner, 0 for full bandwidth (see docs/protocols/digitizer.md).
    """

    sample_rate_hz: int
    record_length: int
    segments: int
    input_range_mv: int
    channel_mask: int
    bits: int
    resolution_bits: int = 0
    bandwidth_hz: int = 0

    def __post_init__(self) -> None:
        if self.resolution_bits == 0:
            object.__setattr__(self, "resolution_bits", self.bits)

    @property
    def channels(self) -> tuple[str, ...]:
        return channels_of(self.channel_mask)


def encode_config(c: Config) -> bytes:
    return _CONFIG.pack(c.sample_rate_hz, c.record_length, c.segments, c.input_range_mv,
                        c.channel_mask, c.bits, c.resolution_bits, 0, c.bandwidth_hz)


def decode_config(data: bytes) -> Config:
    if len(data) != _CONFIG.size:
        raise DigitizerProtocolError(f"config must be {_CONFIG.size} bytes, got {len(data)}")
    rate, rl, seg, rng, mask, bits, res, _r, bw = _CONFIG.unpack(data)
    validate_mask(mask)
    check_resolution(res, bits)
    return Config(rate, rl, seg, rng, mask, bits, res, bw)


# ------------------------------------------------------------------------- segment header


def encode_segment_header(h: SegmentHeader) -> bytes:
    validate_mask(h.channel_mask)
    bytes_per_sample(h.bits)
    head = HEADER.pack(MAGIC, VERSION, h.bits, h.channel_mask, h.overrange, h.index, h.n_samples,
                       h.trigger_time_ns, h.payload_crc32, 0)
    return head[:28] + struct.pack("<I", zlib.crc32(head[:28]))


def encode_segment(index: int, trigger_time_ns: int, channel_mask_: int, bits: int,
                   overrange: int, samples: np.ndarray) -> bytes:
    """Header + payload for one segment; ``samples`` shape (n_channels, n_samples)."""
    dt = sample_dtype(bits)
    payload = np.ascontiguousarray(samples, dtype=dt).tobytes()
    n_ch = bin(channel_mask_).count("1")
    if samples.ndim != 2 or samples.shape[0] != n_ch:
        raise DigitizerProtocolError(f"samples shape {samples.shape} does not match {n_ch} channels")
    h = SegmentHeader(index, trigger_time_ns, samples.shape[1], channel_mask_, bits, overrange,
                      zlib.crc32(payload))
    return encode_segment_header(h) + payload


def decode_segment_header(data: bytes | memoryview) -> SegmentHeader:
    if len(data) < HEADER_LEN:
        raise DigitizerProtocolError(f"segment header needs {HEADER_LEN} bytes, got {len(data)}")
    raw = bytes(data[:HEADER_LEN])
    magic, ver, bits, mask, ovr, idx, ns, t_ns, pcrc, hcrc = HEADER.unpack(raw)
    if magic != MAGIC:
        raise DigitizerProtocolError(f"bad segment magic {magic!r}")
    if zlib.crc32(raw[:28]) != hcrc:
        raise DigitizerProtocolError("segment header crc32 mismatch")
    if ver != VERSION:
        raise DigitizerProtocolError(f"unsupported segment header version {ver}")
    bytes_per_sample(bits)
    validate_mask(mask)
    if ovr >> bin(mask).count("1"):
        raise DigitizerProtocolError(f"overrange flags 0x{ovr:02x} name absent channels")
    return SegmentHeader(idx, t_ns, ns, mask, bits, ovr, pcrc)


def decode_segment(data: bytes | memoryview) -> tuple[SegmentHeader, np.ndarray, int]:
    """One whole segment at the start of ``data`` -> (header, samples (n_ch, n), bytes used)."""
    h = decode_segment_header(data)
    end = HEADER_LEN + h.payload_len
    if len(data) < end:
        raise DigitizerProtocolError(f"segment {h.index} truncated: need {end} bytes, have {len(data)}")
    payload = memoryview(data)[HEADER_LEN:end]
    if zlib.crc32(payload) != h.payload_crc32:
        raise DigitizerProtocolError(f"segment {h.index} payload crc32 mismatch")
    arr = np.frombuffer(payload, dtype=sample_dtype(h.bits)).reshape(h.n_channels, h.n_samples)
    return h, arr.copy(), end


class SegmentStreamParser:
    """Incremental parser of the bulk-IN segment stream that resynchronizes after garbage.

    On anything that is not a valid header (magic + header crc) it scans forward to the next
    ``DGSG``; a segment whose payload crc fails is dropped and counted in ``crc_errors``; the
    next header is searched for right after the bad header, so one damaged segment never hides
    the next good one. ``max_payload`` bounds the memory a corrupted length field can demand.
    """

    def __init__(self, max_payload: int = 64 * 1024 * 1024) -> None:
        self._buf = bytearray()
        self.max_payload = max_payload
        self.dropped_bytes = 0
        self.crc_errors = 0

    def feed(self, data: bytes | bytearray | memoryview) -> list[tuple[SegmentHeader, np.ndarray]]:
        self._buf += data
        buf = self._buf
        out: list[tuple[SegmentHeader, np.ndarray]] = []
        pos = 0
        while True:
            k = buf.find(MAGIC, pos)
            if k < 0:
                keep = max(pos, len(buf) - 3)  # a magic may straddle the next feed
                self.dropped_bytes += keep - pos
                pos = keep
                break
            self.dropped_bytes += k - pos
            pos = k
            if len(buf) - pos < HEADER_LEN:
                break
            try:
                h = decode_segment_header(bytes(buf[pos:pos + HEADER_LEN]))
                if h.payload_len > self.max_payload:
                    raise DigitizerProtocolError("payload too large")
            except DigitizerProtocolError:
                pos += 1
                self.dropped_bytes += 1
                continue
            end = pos + HEADER_LEN + h.payload_len
            if len(buf) < end:
                break
            payload = bytes(buf[pos + HEADER_LEN:end])  # a copy: no view may pin buf (del below)
            if zlib.crc32(payload) != h.payload_crc32:
                self.crc_errors += 1
                pos += 1
                self.dropped_bytes += 1
                continue
            arr = np.frombuffer(payload, dtype=sample_dtype(h.bits)).reshape(h.n_channels, h.n_samples)
            out.append((h, arr))
            pos = end
        del buf[:pos]
        return out


__all__ = ["ALL_CHANNELS_MASK", "CHANNEL_BITS", "CONFIG_LEN", "Config", "DIGITIZER_PID", "DIGITIZER_VID",
           "DigitizerProtocolError", "EP_DATA_IN", "HEADER", "HEADER_CRC_SPAN", "HEADER_LEN", "MAGIC", "MAX_BANDWIDTH_HZ",
           "MIN_RESOLUTION_BITS", "REQTYPE_IN", "REQTYPE_OUT", "Req", "SegmentHeader", "SegmentHeaders",
           "SegmentStreamParser",
           "State", "Status", "VERSION", "bytes_per_sample", "channel_mask", "channels_of",
           "check_resolution", "dec_read_segments", "dec_u32", "dec_u64", "decode_config", "decode_segment",
           "decode_segment_header", "decode_status", "enc_read_segments", "enc_u32", "enc_u64",
           "encode_config", "encode_segment", "encode_segment_header", "encode_status", "header_column",
           "header_crc32s", "overrange_flags", "payload_crc32s",
           "sample_dtype", "segment_bytes", "segment_dtype", "validate_mask"]
