"""AWG driver: typed methods over USBTMC/SCPI on a pyusb ``Device``.

§4.4.1: the AWG plays the pre-distorted laser-modulation waveform (§2.2 iterative learning
pre-distortion), one period per external trigger from the FPGA (burst mode) so the chirp stays in
step with the FPSA pixel switching. The driver talks to whatever ``usb.core.Device`` it is given; the
caller found it with ``usb.core.find(idVendor=..., idProduct=..., backend=backend)`` where the
backend comes from configuration (libusb1 in the lab, the simulated backend on the bench). There is
no knowledge of simulation here.

Every setting command is followed by ``SYST:ERR?`` so a device-side SCPI error is raised as
``AwgError`` naming the command that caused it. USB timeouts are retried a bounded number of times
(the whole message is resent with a fresh bTag), then ``DeviceTimeout("awg", command)``.

Reconnect: given a ``finder`` (a callable that runs ``usb.core.find`` for the AWG's VID:PID again), a
transfer that fails because the device went away (ENODEV) makes the driver look for the device again
(bounded, with ``backoff_s * 2**k`` between looks through the injected ``sleep``), set its
configuration, and resend the message; a device that stays away ends in ``DeviceDisconnected``
naming the command. Without a finder a disconnect is raised at once.
"""

from __future__ import annotations

import errno
import logging
import time
from collections.abc import Callable
from typing import Literal

import numpy as np
import usb.core

from drivers import usbtmc
from drivers.awg import protocol as p
from drivers.errors import CommandRefused, ProtocolError
from drivers.retry import RetryPolicy
from drivers.usb_refind import refind_device
from drivers.usbtmc import (
    DeviceDisconnected,
    DeviceTimeout,
    InvalidArgument,
    UsbDeviceError,
    classify_usb_error,
)

log = logging.getLogger(__name__)

DEVICE = "awg"
#: bytes per DEV_DEP_MSG_OUT transfer; a waveform upload is split into this many-byte chunks
CHUNK_BYTES = 1 << 20
#: largest answer we ask for per REQUEST_DEV_DEP_MSG_IN
READ_CHUNK = 64 * 1024


class AwgError(UsbDeviceError, CommandRefused):
    """The AWG reported a SCPI error (code and text) for the named command."""

    def __init__(self, command: str, code: int, text: str) -> None:
        self.code = code
        self.text = text
        super().__init__(DEVICE, command, f"SCPI error {code}: {text}")


class AwgDriver:
    """Typed AWG control. ``device`` is a pyusb ``usb.core.Device``."""

    def __init__(self, device: usb.core.Device, *, timeout_ms: int = 2000, retries: int = 3,
                 ep_out: int = p.AWG_EP_OUT, ep_in: int = p.AWG_EP_IN,
                 finder: Callable[[], usb.core.Device | None] | None = None,
                 sleep: Callable[[float], object] = time.sleep, backoff_s: float = 0.05) -> None:
        if device is None:
            raise DeviceTimeout(DEVICE, "usb.core.find", "no AWG found on the USB backend")
        self._dev = device
        self._finder = finder
        # a timed-out transfer has waited timeout_ms already: re-sent at once; the looks for a
        # replugged device are spaced by backoff_s (doubling) on the injected clock
        self._transfers = RetryPolicy.retries(retries, 0.0, sleep)
        self._refind = RetryPolicy.retries(retries, backoff_s, sleep)
        self.reconnect_count = 0
        self._timeout_ms = int(timeout_ms)
        self._ep_out = ep_out
        self._ep_in = ep_in
        self._btag = 0
        self._rxbuf = usbtmc.HEADER_LEN + READ_CHUNK + 4
        try:
            device.set_configuration()
        except usb.core.USBError as exc:
            raise classify_usb_error(exc, DEVICE, "set_configuration") from exc

    # ----------------------------------------------------------------------- transport

    def _tag(self) -> int:
        self._btag = usbtmc.next_btag(self._btag)
        return self._btag

    def _send(self, message: bytes) -> None:
        msg = message + b"\n"
        n = len(msg)
        pos = 0
        while True:
            chunk = msg[pos:pos + CHUNK_BYTES]
            pos += len(chunk)
            self._dev.write(self._ep_out, usbtmc.encode_dev_dep_msg_out(self._tag(), chunk, pos >= n),
                            self._timeout_ms)
            if pos >= n:
                return

    def _receive(self) -> bytes:
        parts: list[bytes] = []
        while True:
            tag = self._tag()
            self._dev.write(self._ep_out, usbtmc.encode_request_dev_dep_msg_in(tag, READ_CHUNK),
                            self._timeout_ms)
            raw = self._dev.read(self._ep_in, self._rxbuf, self._timeout_ms)
            data, eom = usbtmc.decode_dev_dep_msg_in(memoryview(raw), tag)
            parts.append(data)
            if eom:
                return b"".join(parts).rstrip(b"\r\n")

    def reconnect(self, command: str = "reconnect") -> None:
        """Find the device again (VID:PID, through ``finder``) and set its configuration.

        Tries ``retries + 1`` times with exponential backoff; ``DeviceDisconnected`` if it stays away.
        """
        self._dev = refind_device(self._finder, device=DEVICE, command=command, policy=self._refind)
        self._btag = 0
        self.reconnect_count += 1
        log.warning("awg: reconnected after %s", command)

    def _transact(self, message: bytes, query: bool) -> bytes:
        name = message[:40].decode("ascii", "replace")
        last: Exception | None = None
        err: Exception | None = None
        try:
            for attempt in self._transfers.tries():
                try:
                    self._send(message)
                    return self._receive() if query else b""
                except usb.core.USBError as exc:
                    err = classify_usb_error(exc, DEVICE, name)
                    if isinstance(err, DeviceDisconnected) and self._finder is not None:
                        log.warning("awg: %s (attempt %d/%d); looking for the device again", err,
                                    attempt + 1, self._transfers.attempts)
                        self.reconnect(name)
                        last = exc
                        continue
                    if not isinstance(err, DeviceTimeout):
                        if getattr(exc, "errno", None) == errno.EPIPE:
                            # a stalled bulk pipe stays halted until cleared; leave it usable
                            self._clear_halts()
                        raise err from exc
                    last = exc
                    self._clear_buffers()
                    log.warning("awg: timeout on %r (attempt %d/%d)", name, attempt + 1, self._transfers.attempts)
                except ProtocolError as exc:
                    raise UsbDeviceError(DEVICE, name, f"bad reply: {exc}") from exc
            raise DeviceTimeout(DEVICE, name, f"no answer after {self._transfers.attempts} attempts") from last
        finally:
            # a kept exception's traceback holds this frame (see DigitizerDriver._guard)
            last = err = None

    def _clear_buffers(self) -> None:
        """USBTMC INITIATE_CLEAR + CHECK_CLEAR_STATUS: the device drops partial input and unread
        output, so a retried query cannot be answered by a stale reply."""
        try:
            st = self._dev.ctrl_transfer(usbtmc.REQTYPE_CLASS_INTERFACE_IN, usbtmc.REQ_INITIATE_CLEAR,
                                         0, 0, 1, self._timeout_ms)
            if len(st) and st[0] == usbtmc.STATUS_SUCCESS:
                for _ in range(16):
                    st = self._dev.ctrl_transfer(usbtmc.REQTYPE_CLASS_INTERFACE_IN,
                                                 usbtmc.REQ_CHECK_CLEAR_STATUS, 0, 0, 2, self._timeout_ms)
                    if not len(st) or st[0] != usbtmc.STATUS_PENDING:
                        break
        except usb.core.USBError as exc:
            log.warning("awg: USBTMC clear failed: %s", exc)

    def _clear_halts(self) -> None:
        for ep in (self._ep_out, self._ep_in):
            try:
                self._dev.clear_halt(ep)
            except usb.core.USBError:
                pass

    def query(self, message: bytes) -> bytes:
        return self._transact(message, True)

    def write(self, message: bytes) -> None:
        """Send a setting command and raise ``AwgError`` if the device queued an error for it."""
        self._transact(message, False)
        errs = self._drain_errors()
        if errs:
            code, text = errs[0]
            raise AwgError(message[:40].decode("ascii", "replace"), code, text)

    def _drain_errors(self) -> list[tuple[int, str]]:
        out: list[tuple[int, str]] = []
        for _ in range(64):  # the queue is bounded on the device; never loop forever
            code, text = p.parse_error(self.query(p.cmd_err()))
            if code == 0:
                break
            out.append((code, text))
        return out

    # ----------------------------------------------------------------------- typed API

    def identify(self) -> p.Identity:
        return p.parse_idn(self.query(p.cmd_idn()))

    def reset(self) -> None:
        """*CLS;*RST: error queue emptied first (so stale errors are not blamed on the reset),
        then defaults restored, output off."""
        self.write(p.cmd_cls() + b";" + p.cmd_rst())

    def errors(self) -> list[tuple[int, str]]:
        """Drain the device error queue: list of (code, text), oldest first."""
        return self._drain_errors()

    def set_sample_rate(self, hz: float) -> None:
        if not (np.isfinite(hz) and hz > 0):
            raise InvalidArgument(DEVICE, "set_sample_rate", f"awg sample rate must be > 0 Hz, got {hz!r}")
        self.write(p.cmd_sample_rate(hz))

    def sample_rate(self) -> float:
        return p.parse_float(self.query(b"SOUR:FREQ:SAMP?"))

    def set_amplitude(self, v: float) -> None:
        if not (np.isfinite(v) and v > 0):
            raise InvalidArgument(DEVICE, "set_amplitude", f"awg amplitude must be > 0 V, got {v!r}")
        self.write(p.cmd_amplitude(v))

    def amplitude(self) -> float:
        return p.parse_float(self.query(b"SOUR:VOLT?"))

    def set_offset(self, v: float) -> None:
        if not np.isfinite(v):
            raise InvalidArgument(DEVICE, "set_offset", f"awg offset must be finite, got {v!r}")
        self.write(p.cmd_offset(v))

    def offset(self) -> float:
        return p.parse_float(self.query(b"SOUR:VOLT:OFFS?"))

    def set_trigger_external(self, external: bool) -> None:
        """External trigger = burst mode: one waveform period per trigger edge."""
        self.write(p.cmd_trigger_source(bool(external)))

    def output(self, on: bool) -> None:
        self.write(p.cmd_output(bool(on)))

    def output_on(self) -> bool:
        return p.parse_int(self.query(b"OUTP?")) == 1

    def waveform_points(self) -> int:
        return p.parse_int(self.query(b"SOUR:DATA:ARB:POIN?"))

    def upload_waveform(self, samples: np.ndarray,
                        units: Literal["normalized", "volts"] = "normalized") -> None:
        """Upload one waveform period.

        ``normalized``: samples in [-1, 1] are DAC full scale (amplitude/offset unchanged).
        ``volts``: the driver sets offset = (max+min)/2 and amplitude = (max-min)/2 so the
        waveform spans the full DAC range, then uploads the normalized codes.
        """
        s = np.asarray(samples, dtype=np.float64)
        if s.ndim != 1 or s.size < 2:
            raise InvalidArgument(DEVICE, "upload_waveform", f"awg waveform must be 1-D with >= 2 samples, got shape {s.shape}")
        if not np.all(np.isfinite(s)):
            raise InvalidArgument(DEVICE, "upload_waveform", "awg waveform contains non-finite samples")
        if units == "volts":
            hi, lo = float(s.max()), float(s.min())
            amp = (hi - lo) / 2.0
            off = (hi + lo) / 2.0
            if amp <= 0:
                raise InvalidArgument(DEVICE, "upload_waveform", "awg waveform in volts is constant: amplitude would be 0 V")
            s = np.clip((s - off) / amp, -1.0, 1.0)
            # The output stage checks |offset| + amplitude on every setting, so go through offset 0:
            # (0, old amp) and (0, new amp) are valid whenever the old and the new settings are, while
            # (old offset, new amp) need not be.
            self.set_offset(0.0)
            self.set_amplitude(amp)
            self.set_offset(off)
        elif units != "normalized":
            raise InvalidArgument(DEVICE, "upload_waveform", f"awg waveform units must be 'normalized' or 'volts', got {units!r}")
        elif np.max(np.abs(s)) > 1.0:
            raise InvalidArgument(DEVICE, "upload_waveform", f"awg normalized waveform exceeds [-1, 1] (max |s| = {np.max(np.abs(s))})")
        self.write(p.cmd_upload(p.codes_from_normalized(s)))
