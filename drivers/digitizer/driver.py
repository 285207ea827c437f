"""Digitizer driver: typed methods over the vendor USB protocol (drivers/digitizer/protocol.py).

§4.4.1: the ADC samples the beat (and optionally the MZI reference and I/Q beat) once per external
trigger, i.e. one segment per chirp per FPSA pixel, and hands the records to the PC. The driver gets
a pyusb ``Device`` from the caller (``usb.core.find(..., backend=backend)``, backend from
configuration); it does not know whether the bus is real or simulated.

Bulk data is read in large transfers (1 MiB by default) into kept transfer buffers and parsed with
a numpy record dtype (``np.frombuffer``; a read that one transfer fills is parsed in that buffer, and
the samples are copied out): per-segment work is two crc32 calls, per-sample work is none in Python,
and the headers come back as columns (``SegmentHeaders``), not one object per segment. A refused control request (STALL) becomes ``DigitizerError`` naming the request;
timeouts are retried a bounded number of times then ``DeviceTimeout("digitizer", command)``.

Reconnect: with a ``finder`` (``usb.core.find`` for the digitizer's VID:PID again), a transfer that
fails with ENODEV makes the driver find the device again (bounded, backoff through the injected
``sleep``), set its configuration and repeat the transfer; ``DeviceDisconnected`` if it stays away.
A multi-transfer operation (``read_segments``) is not resumed half-way by the driver: the caller
re-reads the batch (segments are addressed by index, so a re-read is idempotent).
"""

from __future__ import annotations

import array
import logging
import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np
import usb.core

from drivers.digitizer import protocol as p
from drivers.errors import ProtocolError
from drivers.retry import RetryPolicy
from drivers.usb_refind import refind_device
from drivers.usbtmc import (
    DeviceDisconnected,
    DeviceStall,
    DeviceTimeout,
    InvalidArgument,
    UsbDeviceError,
    classify_usb_error,
)

log = logging.getLogger(__name__)

DEVICE = "digitizer"
T = TypeVar("T")


class DigitizerError(DeviceStall):
    """The digitizer refused a request (stalled the control pipe): bad value or wrong state."""


class DigitizerDataError(UsbDeviceError, ProtocolError):
    """Segment stream that fails validation (magic, index, crc) for the named read."""


class DigitizerDriver:
    """Typed digitizer control. ``device`` is a pyusb ``usb.core.Device``."""

    def __init__(self, device: usb.core.Device, *, timeout_ms: int = 2000, retries: int = 3,
                 chunk_bytes: int = 1 << 20, finder: Callable[[], usb.core.Device | None] | None = None,
                 sleep: Callable[[float], object] = time.sleep, backoff_s: float = 0.05) -> None:
        if device is None:
            raise DeviceTimeout(DEVICE, "usb.core.find", "no digitizer found on the USB backend")
        self._dev = device
        self._finder = finder
        # a timed-out transfer has waited timeout_ms already: re-sent at once; the looks for a
        # replugged device are spaced by backoff_s (doubling) on the injected clock
        self._transfers = RetryPolicy.retries(retries, 0.0, sleep)
        self._refind = RetryPolicy.retries(retries, backoff_s, sleep)
        self.reconnect_count = 0
        self._timeout_ms = int(timeout_ms)
        self._chunk = array.array("B", bytes(chunk_bytes))
        self._spare: dict[int, array.array[int]] = {}     # transfer buffers of other sizes, by size
        try:
            device.set_configuration()
        except usb.core.USBError as exc:
            raise classify_usb_error(exc, DEVICE, "set_configuration") from exc

    # -------------------------------------------------------------------- transport

    def reconnect(self, command: str = "reconnect") -> None:
        """Find the device again (VID:PID, through ``finder``) and set its configuration.

        Tries ``retries + 1`` times with exponential backoff; ``DeviceDisconnected`` if it stays away.
        """
        self._dev = refind_device(self._finder, device=DEVICE, command=command, policy=self._refind)
        self.reconnect_count += 1
        log.warning("digitizer: reconnected after %s", command)

    def _guard(self, command: str, fn: Callable[[], T], retry: bool = True) -> T:
        last: Exception | None = None
        err: Exception | None = None
        try:
            for attempt in (self._transfers if retry else RetryPolicy(1)).tries():
                try:
                    return fn()
                except usb.core.USBError as exc:
                    err = classify_usb_error(exc, DEVICE, command)
                    if isinstance(err, DeviceDisconnected) and self._finder is not None and retry:
                        log.warning("digitizer: %s (attempt %d); looking for the device again", err, attempt + 1)
                        self.reconnect(command)
                        last = exc
                        continue
                    if isinstance(err, DeviceStall):
                        raise DigitizerError(DEVICE, command, "request refused (STALL)") from exc
                    if not isinstance(err, DeviceTimeout):
                        raise err from exc
                    last = exc
                    log.warning("digitizer: timeout on %s (attempt %d)", command, attempt + 1)
            raise DeviceTimeout(DEVICE, command, f"no answer after {attempt + 1} attempts") from last
        finally:
            # a kept exception's traceback holds this frame, and the frame these locals: a cycle only
            # the cyclic collector frees, which pins every caller's frame and its arrays meanwhile
            last = err = None

    def _out(self, req: p.Req, w_value: int = 0, data: bytes = b"") -> None:
        self._guard(req.name, lambda: self._dev.ctrl_transfer(
            p.REQTYPE_OUT, int(req), w_value, 0, data, self._timeout_ms))

    def _in(self, req: p.Req, length: int) -> bytes:
        return bytes(self._guard(req.name, lambda: self._dev.ctrl_transfer(
            p.REQTYPE_IN, int(req), 0, 0, length, self._timeout_ms)))

    # -------------------------------------------------------------------- typed API

    def identify(self) -> str:
        return self._in(p.Req.IDENTIFY, 64).rstrip(b"\x00").decode("ascii", "replace")

    def set_channels(self, channels: tuple[str, ...]) -> None:
        """("beat",), ("beat", "mzi"), ("beat_i", "beat_q"), ("beat_i", "beat_q", "mzi"), ..."""
        try:
            mask = p.channel_mask(tuple(channels))
        except p.DigitizerProtocolError as exc:
            raise InvalidArgument(DEVICE, "set_channels", f"digitizer channels {channels!r}: {exc}") from None
        self._out(p.Req.SET_CHANNELS, mask)

    def set_sample_rate(self, hz: float) -> None:
        if not (np.isfinite(hz) and hz >= 1):
            raise InvalidArgument(DEVICE, "set_sample_rate", f"digitizer sample rate must be >= 1 Hz, got {hz!r}")
        self._out(p.Req.SET_SAMPLE_RATE, data=p.enc_u64(int(round(hz))))

    def set_record_length(self, n: int) -> None:
        if not 1 <= int(n) <= 0xFFFFFFFF:
            raise InvalidArgument(DEVICE, "set_record_length", f"digitizer record length {n!r} out of u32 range")
        self._out(p.Req.SET_RECORD_LENGTH, data=p.enc_u32(int(n)))

    def set_segments(self, n: int) -> None:
        if not 1 <= int(n) <= 0xFFFFFFFF:
            raise InvalidArgument(DEVICE, "set_segments", f"digitizer segment count {n!r} out of u32 range")
        self._out(p.Req.SET_SEGMENTS, data=p.enc_u32(int(n)))

    def set_format(self, bits: int) -> None:
        if bits not in (8, 16):
            raise InvalidArgument(DEVICE, "set_format", f"digitizer sample format must be 8 or 16 bits, got {bits!r}")
        self._out(p.Req.SET_FORMAT, bits)

    def set_input_range(self, volts: float) -> None:
        mv = int(round(volts * 1000.0)) if np.isfinite(volts) else -1
        if not 1 <= mv <= 0xFFFFFFFF:
            raise InvalidArgument(DEVICE, "set_input_range", f"digitizer input range {volts!r} V out of range")
        self._out(p.Req.SET_RANGE, data=p.enc_u32(mv))

    def set_resolution(self, bits: int) -> None:
        """Quantize the samples to ``bits`` (8 .. the sample format's bits; set the format first).

        A 12-bit resolution in the 16-bit format gives codes that are multiples of 16.
        """
        if isinstance(bits, bool) or not isinstance(bits, int) or not p.MIN_RESOLUTION_BITS <= bits <= 16:
            raise InvalidArgument(DEVICE, "set_resolution",
                                  f"digitizer resolution must be an integer of {p.MIN_RESOLUTION_BITS}..16 "
                                  f"bits, got {bits!r}")
        self._out(p.Req.SET_RESOLUTION, bits)

    def set_bandwidth(self, hz: float | None) -> None:
        """Anti-alias low-pass corner in Hz (the -3 dB point); ``None`` or 0 = full bandwidth.

        The response is documented in docs/protocols/digitizer.md ("Bandwidth limit"); a corner at
        or above half the sample rate leaves the record unfiltered.
        """
        value = 0.0 if hz is None else hz
        if not (np.isfinite(value) and (value == 0 or 1 <= value <= p.MAX_BANDWIDTH_HZ)):
            raise InvalidArgument(DEVICE, "set_bandwidth",
                                  f"digitizer bandwidth must be 0 (full) or 1 .. {p.MAX_BANDWIDTH_HZ:g} Hz, "
                                  f"got {hz!r}")
        self._out(p.Req.SET_BANDWIDTH, data=p.enc_u64(int(round(value))))

    def configure(self, *, channels: tuple[str, ...], sample_rate_hz: float, record_length: int,
                  segments: int, bits: int = 16, input_range_v: float = 1.0,
                  resolution_bits: int | None = None, bandwidth_hz: float | None = None) -> p.Config:
        """All settings in one call; returns the device's read-back configuration.

        ``bits`` is the sample format (8 or 16); ``resolution_bits`` the ADC resolution the samples
        are quantized to (default: the format's bits); ``bandwidth_hz`` the anti-alias corner
        (default: full bandwidth). Every call sets all of them, so nothing is left over from a
        previous configuration.
        """
        self.set_channels(channels)
        self.set_sample_rate(sample_rate_hz)
        self.set_record_length(record_length)
        self.set_segments(segments)
        self.set_format(bits)
        self.set_resolution(bits if resolution_bits is None else resolution_bits)
        self.set_bandwidth(bandwidth_hz)
        self.set_input_range(input_range_v)
        return self.config()

    def config(self) -> p.Config:
        return p.decode_config(self._in(p.Req.GET_CONFIG, p.CONFIG_LEN))

    def arm(self) -> None:
        self._out(p.Req.ARM)

    def abort(self) -> None:
        self._out(p.Req.ABORT)

    def status(self) -> p.Status:
        return p.decode_status(self._in(p.Req.GET_STATUS, 16))

    def read_segments(self, first: int, count: int,
                      cfg: p.Config | None = None) -> tuple[p.SegmentHeaders, np.ndarray]:
        """Read segments ``first .. first+count-1`` of the current acquisition.

        Returns (headers, samples) with samples shaped (count, n_channels, record_length), dtype
        int16 or int8 following the configured format; ``headers`` is a sequence of
        ``SegmentHeader`` that also holds each field as an array (``headers.trigger_time_ns``,
        ``headers.overrange``). ``cfg`` (from ``config()``) saves a control round trip when the
        caller already has it.
        """
        if count < 1 or first < 0:
            raise InvalidArgument(DEVICE, "read_segments", f"digitizer read_segments(first={first}, count={count}) invalid")
        cfg = cfg or self.config()
        n_ch = len(cfg.channels)
        rec = p.segment_dtype(n_ch, cfg.record_length, cfg.bits)
        command = f"READ_SEGMENTS({first},{count})"
        self._guard(command, lambda: self._dev.ctrl_transfer(
            p.REQTYPE_OUT, int(p.Req.READ_SEGMENTS), 0, 0, p.enc_read_segments(first, count),
            self._timeout_ms))
        raw = self._read_stream(rec.itemsize * count, command)
        recs = raw.view(rec)
        self._validate(recs, raw, first, count, cfg, command)
        headers = p.SegmentHeaders.from_records(recs)   # columns, copied: ``raw`` may be a reused buffer
        samples = np.array(recs["data"], copy=True)     # a copy: ``raw`` may be a reused transfer buffer
        if cfg.bits == 16:
            samples = samples.astype(np.int16, copy=False)
        else:
            samples = samples.astype(np.int8, copy=False)
        return headers, samples

    def _read_stream(self, total: int, command: str) -> np.ndarray:
        """``total`` bytes of the bulk-IN stream as uint8; the array may be one of the driver's
        transfer buffers, valid until the next read (read_segments copies the samples out).

        Each transfer asks for exactly the bytes still due, at most ``chunk_bytes`` (a device
        that has sent all it has ends the transfer without a zero-length packet). A read that one
        transfer fills is parsed in the transfer buffer itself: no copy."""
        first = self._transfer_buffer(min(len(self._chunk), total))
        n = self._bulk_in(first, command, 0, total)
        if n == total:
            return np.frombuffer(first, dtype=np.uint8)
        out = np.empty(total, dtype=np.uint8)
        out[:n] = np.frombuffer(first, dtype=np.uint8, count=n)
        pos = n
        while pos < total:
            buf = self._transfer_buffer(min(len(self._chunk), total - pos))
            n = self._bulk_in(buf, command, pos, total)
            out[pos:pos + n] = np.frombuffer(buf, dtype=np.uint8, count=n)
            pos += n
        return out

    def _bulk_in(self, buf: array.array[int], command: str, pos: int, total: int) -> int:
        n = self._guard(command, lambda: self._dev.read(p.EP_DATA_IN, buf, self._timeout_ms))
        if n <= 0:
            raise DigitizerDataError(DEVICE, command, f"empty bulk transfer at byte {pos} of {total}")
        return n

    def _transfer_buffer(self, size: int) -> array.array[int]:
        """An array of exactly ``size`` bytes for one transfer (pyusb reads len(buffer) bytes):
        the chunk, or a kept buffer of that size (a scan's reads repeat a few sizes)."""
        if size == len(self._chunk):
            return self._chunk
        buf = self._spare.get(size)
        if buf is None:
            if len(self._spare) >= 4:
                self._spare.pop(next(iter(self._spare)))
            buf = self._spare[size] = array.array("B", bytes(size))
        return buf

    @staticmethod
    def _validate(recs: np.ndarray, raw: np.ndarray, first: int, count: int, cfg: p.Config,
                  command: str) -> None:
        if not np.all(recs["magic"] == p.MAGIC):
            raise DigitizerDataError(DEVICE, command, "segment magic missing: stream out of step")
        expect = np.arange(first, first + count, dtype=np.uint64)
        if not np.array_equal(recs["index"].astype(np.uint64), expect):
            raise DigitizerDataError(DEVICE, command, "segment indices out of sequence")
        if not (np.all(recs["n_samples"] == cfg.record_length) and np.all(recs["mask"] == cfg.channel_mask)
                and np.all(recs["bits"] == cfg.bits)):
            raise DigitizerDataError(DEVICE, command, "segment header does not match configuration")
        mv, size = raw.data, recs.dtype.itemsize
        # every segment's two crc32s, then one comparison per field; the first segment that fails
        # (header before payload, as a segment at a time would find it) names the error
        bad_header = np.flatnonzero(np.asarray(p.header_crc32s(mv, size, count), np.uint32) != recs["header_crc32"])
        bad_payload = np.flatnonzero(np.asarray(p.payload_crc32s(mv, size, count), np.uint32) != recs["payload_crc32"])
        if bad_header.size or bad_payload.size:
            i = min(bad_header[:1].tolist() + bad_payload[:1].tolist())
            what = "header" if i in bad_header[:1] else "payload"
            raise DigitizerDataError(DEVICE, command, f"segment {first + i} {what} crc32 mismatch")

