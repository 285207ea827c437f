"""Host driver of the FPSA controller FPGA (§4.3.3, Fig. 4-22): typed methods over the wire
codec in ``protocol.py`` and a :class:`drivers.transport.ByteChannel`.

The seam is the channel (pyserial's idea; httpx's transport seam is the model): the driver takes
any object with ``read``/``write``/``timeout`` (``FpsaController(channel, reopen=...)``), and
``FpsaController.from_url(url)`` opens one through :func:`drivers.transport.open_channel`. The same
class drives the Cmod-S7 on ``/dev/ttyUSB1``, the simulated FPGA on a pty path, or the simulator's
in-memory pipe; tests wrap a channel to drop or corrupt bytes. There is no simulator switch: the
channel is configuration. (``FpsaController(url)`` still works for one release, with a
DeprecationWarning.)

Reliability (stop-and-wait with idempotent retries): every command gets a fresh ``seq``; a
retry re-sends the *identical* frame (same seq) after a lone 0x00 that flushes any garbage the
FPGA is holding, so the FPGA answers a duplicate from its response cache instead of executing it
twice. No answer within ``timeout_s`` (an empty read), a garbled answer, or NAK BAD_CRC ->
retry after ``backoff_s * 2**k``; after ``retries`` retries -> :class:`DeviceTimeout` naming the
device and the command (or :class:`LinkError` if answers kept arriving garbled). Any other NAK is
final and raised as :class:`NakError`.

Reconnect: when the port itself fails (the USB-serial adapter unplugged, the pty closed: pyserial
raises ``SerialException``/``OSError``), a driver with ``reopen`` closes it and opens a fresh
channel before the next attempt (``from_url`` reopens the SAME URL); without ``reopen`` the failure
is final, a :class:`~drivers.errors.DeviceGone` naming device and command. The URL should therefore be a stable name (``/dev/serial/by-id/...`` in
the lab, the bench's symlink in simulation) that follows the device to its new node. The retry
budget is shared with timeouts, so a port that stays away ends in :class:`DeviceTimeout` (or
:class:`~drivers.errors.DeviceGone` when it cannot even be reopened) naming the device.

Patterns are validated before anything is sent: shape, range, and that every row is wire-bonded
(§4.3.3: one row in four is not). The protocol can only ever address one row per pixel
(SET_PIXEL and pattern entries are single (row, col) pairs), so the host never commands two
rows at once. The check itself is ``drivers/fpsa/patterns.py`` (pure).
"""

from __future__ import annotations

import functools
import logging
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import serial

from drivers.errors import DeviceGone, InvalidValue, LinkError, ProtocolError
from drivers.retry import RetryPolicy
from drivers.transport import ByteChannel, DeviceTimeout, TracedChannel, TransportError, open_channel

from . import protocol as p
from .errors import NakError
from .link import ChipLayout, FpsaLink
from .patterns import validate_pixels

log = logging.getLogger(__name__)

DEFAULT_BAUDRATE = 3_000_000  # see docs/protocols/fpsa.md, "Physical link"
_MIN_CHUNK_PIXELS = 32        # smallest chunk the upload falls back to on a noisy line

__all__ = ["DEFAULT_BAUDRATE", "ChipLayout", "FpsaController", "FpsaLink", "LinkError"]

_DEFAULT_LINK = FpsaLink()        # 0.5 s replies, 3 retries from 10 ms, 1024-pixel frames, the wall clock
_UNKNOWN_CHIP = ChipLayout()      # the chip's layout as the board reports it


def _url_opener(url: str, baudrate: int, timeout_s: float, trace: bool,
                device: str) -> Callable[[], ByteChannel]:
    """A function that opens ``url`` afresh each call (the driver's ``reopen``)."""
    return functools.partial(open_channel, url, baudrate=baudrate, timeout_s=timeout_s, trace=trace,
                             device=device)


class FpsaController:
    """Typed, validated access to the FPSA controller over a :class:`ByteChannel`.

    ``FpsaController(channel, reopen=...)`` drives any open channel; ``reopen`` (optional) opens a
    fresh channel to the same device when the port itself fails (see the module docstring).
    ``FpsaController.from_url(url, ...)`` is the usual way in: it opens the URL through
    :func:`drivers.transport.open_channel` and reopens the same URL on a port failure. The driver
    closes the channels it opened (through ``from_url`` or ``reopen``); a channel passed in is the
    caller's to close. ``link``: timeouts, retries, upload chunks and clocks (:class:`FpsaLink`);
    ``chip``: what is known of the chip's layout beforehand (:class:`ChipLayout`).
    """

    def __init__(
        self,
        channel: ByteChannel | str,
        *,
        reopen: Callable[[], ByteChannel] | None = None,
        url: str | None = None,
        link: FpsaLink = _DEFAULT_LINK,
        chip: ChipLayout = _UNKNOWN_CHIP,
        baudrate: int = DEFAULT_BAUDRATE,
        trace: bool = False,
        device: str = "fpsa",
    ) -> None:
        link.check(device)
        timeout_s = link.timeout_s
        self.device = device
        self.timeout_s = float(timeout_s)
        self.retries = link.retries
        self.backoff_s = float(link.backoff_s)
        self.chunk_pixels = link.chunk_pixels
        self._sleep = link.sleep
        self._monotonic = link.monotonic
        self.reconnect_count = 0
        self._port_broken = False
        owns = False
        if isinstance(channel, str):
            # The pre-seam call ``FpsaController(url, baudrate=...)``, kept for one release.
            warnings.warn("FpsaController(url) is deprecated: use FpsaController.from_url(url)",
                          DeprecationWarning, stacklevel=2)
            url, reopen = channel, _url_opener(channel, baudrate, timeout_s, trace, device)
            channel, trace, owns = reopen(), False, True
        elif not isinstance(channel, ByteChannel):
            raise TypeError(f"{device}: expected a ByteChannel (read(), write(), timeout) or use "
                            f"FpsaController.from_url(url), got {type(channel).__name__}")
        self.url = url
        self._reopen = reopen
        self._owns_port = owns
        # an empty read must mean "timeout_s passed": never block forever
        channel.timeout = timeout_s
        self._port: ByteChannel = TracedChannel(channel, device=device) if trace else channel
        self._parser = p.FrameParser()
        self._seq = 0
        self._rows = chip.rows
        self._cols = chip.cols
        self._bonded: np.ndarray | None = None
        if chip.bonded_rows is not None:
            self._set_bonded(chip.bonded_rows)
        self.tx_bytes = 0
        self.rx_bytes = 0
        self.retry_count = 0

    @classmethod
    def from_url(cls, url: str, *, baudrate: int = DEFAULT_BAUDRATE, link: FpsaLink = _DEFAULT_LINK,
                 trace: bool = False, device: str = "fpsa", **kwargs: Any) -> FpsaController:
        """Open ``url`` (any scheme of :data:`drivers.transport.SCHEMES`, ``trace+`` prefix allowed)
        and drive it; a failed port is closed and the SAME url reopened before the next attempt.

        Raises :class:`~drivers.errors.TransportError` (or :class:`~drivers.errors.DeviceGone`)
        naming the device when the URL cannot be opened. Other keywords go to the constructor.
        """
        link.check(device)
        opener = _url_opener(url, baudrate, link.timeout_s, trace, device)
        drv = cls(opener(), reopen=opener, url=url, link=link, device=device, **kwargs)
        drv._owns_port = True
        return drv

    # --- lifecycle ------------------------------------------------------------------------------
    def close(self) -> None:
        if self._owns_port:
            _close(self._port)

    def reconnect(self) -> None:
        """Close the port and open a fresh one through ``reopen`` (TransportError if impossible).

        A driver given a channel without ``reopen`` cannot reconnect: TransportError says so.
        """
        if self._reopen is None:
            raise TransportError(self.device, "reconnect",
                                 "cannot reopen a channel that was passed in without reopen=")
        try:
            _close(self._port)
        except Exception:  # a vanished device may fail to close; the reopen is what matters
            pass
        port = self._reopen()
        port.timeout = self.timeout_s
        self._port = port
        self._owns_port = True
        self._parser = p.FrameParser()
        self._port_broken = False
        self.reconnect_count += 1
        log.warning("%s: reopened %s", self.device, self.url or "its channel")

    def __enter__(self) -> FpsaController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- transactions ---------------------------------------------------------------------------
    def _transact(self, cmd: p.Cmd, payload: bytes = b"") -> bytes:
        self._seq = (self._seq + 1) & 0xFF
        seq = self._seq
        frame = p.encode_frame(seq, cmd, payload)
        policy = RetryPolicy.retries(self.retries, self.backoff_s, self._sleep)
        attempts = policy.attempts
        failure = "timeout"
        reopen_error: TransportError | None = None
        try:
            for attempt in policy.tries():   # waited policy.delay_s(attempt) before each retry
                if attempt:
                    self.retry_count += 1
                    log.warning("%s: %s attempt %d/%d after %s (backoff %.3g s)", self.device,
                                cmd.name, attempt + 1, attempts, failure, policy.delay_s(attempt))
                if self._port_broken and self._reopen is not None:
                    try:
                        self.reconnect()
                    except TransportError as exc:
                        reopen_error = exc
                        failure = "port gone"
                        continue
                wire = (b"\x00" + frame) if attempt else frame
                try:
                    self._port.write(wire)
                    self.tx_bytes += len(wire)
                    outcome = self._await(seq, cmd)
                except (serial.SerialException, OSError) as exc:
                    # the port itself failed (device unplugged / pty closed): reopen before retrying
                    log.warning("%s: port error during %s: %s", self.device, cmd.name, exc)
                    self._port_broken = True
                    failure = "port error"
                    if self._reopen is None:
                        raise DeviceGone(self.device, cmd.name, f"port error: {exc}", url=self.url) from exc
                    continue
                if isinstance(outcome, p.Response):
                    if outcome.ok:
                        return outcome.data
                    if outcome.code == p.NakCode.BAD_CRC:
                        failure = "NAK BAD_CRC"
                        continue
                    raise NakError(self.device, cmd.name, outcome.code, outcome.detail)
                failure = outcome
            if failure == "port gone" and reopen_error is not None:
                raise DeviceGone(self.device, cmd.name, f"port could not be reopened after {attempts} "
                                 f"attempts ({reopen_error})", url=self.url) from reopen_error
            if failure in ("timeout", "port error"):
                raise DeviceTimeout(self.device, cmd.name, timeout_s=self.timeout_s,
                                    attempts=attempts, url=self.url)
            raise LinkError(f"{self.device}: no valid answer to {cmd.name} after {attempts} "
                            f"attempts (last: {failure})", device=self.device, command=cmd.name)
        finally:
            # a kept exception's traceback holds this frame, and this frame the exception: a cycle that
            # pins every caller's frame (and its arrays) until the cyclic collector runs
            reopen_error = None

    def _await(self, seq: int, cmd: p.Cmd) -> p.Response | str:
        deadline = self._monotonic() + self.timeout_s
        while True:
            waiting = getattr(self._port, "in_waiting", 0) or 0
            data = self._port.read(max(1, waiting))
            if not data:
                return "timeout"  # the port's read timeout (= timeout_s) expired
            self.rx_bytes += len(data)
            for item in self._parser.feed_all(data):
                if isinstance(item, ProtocolError):
                    log.info("%s: garbled answer to %s: %s", self.device, cmd.name, item)
                    return "garbled answer"
                try:
                    resp = p.decode_response(item)
                except ProtocolError as exc:
                    log.info("%s: bad response to %s: %s", self.device, cmd.name, exc)
                    return "garbled answer"
                if resp.seq != seq or resp.request_cmd != cmd:
                    log.debug("%s: ignoring stale response seq %d to %s", self.device, resp.seq,
                              p.cmd_name(resp.request_cmd))
                    continue
                return resp
            if self._monotonic() > deadline:
                return "timeout"  # bytes kept trickling in, none of them our answer

    # --- geometry -------------------------------------------------------------------------------
    def _set_bonded(self, bonded: Any) -> None:
        rows = self._rows if self._rows is not None else 128
        mask = np.zeros(rows, bool)
        idx = np.asarray(bonded, dtype=np.int64).ravel()
        if idx.size and (idx.min() < 0 or idx.max() >= rows):
            raise InvalidValue(self.device, "configure", f"{self.device}: bonded_rows must lie in 0..{rows - 1}")
        mask[idx] = True
        self._bonded = mask

    def _geometry(self) -> tuple[int, int, np.ndarray]:
        if self._rows is None or self._cols is None or self._bonded is None:
            self.identify()
        assert self._rows is not None and self._cols is not None and self._bonded is not None
        return self._rows, self._cols, self._bonded

    # --- commands -------------------------------------------------------------------------------
    def identify(self) -> p.Identity:
        ident = p.Identity.unpack(self._transact(p.Cmd.IDENTIFY))
        # explicit constructor arguments win over what the board reports
        if self._rows is None:
            self._rows = ident.rows
        if self._cols is None:
            self._cols = ident.cols
        if self._bonded is None:
            self._set_bonded(ident.bonded_rows)
        return ident

    def reset(self) -> None:
        self._transact(p.Cmd.RESET)

    def clear(self) -> None:
        self._transact(p.Cmd.CLEAR)

    def _validate(self, pixels: Any, what: str) -> np.ndarray:
        rows, cols, bonded = self._geometry()
        return validate_pixels(pixels, what, rows, cols, bonded, self.device)

    def set_pixel(self, row: int, col: int) -> None:
        """Statically steer to one pixel: exactly one row line and one column line high."""
        px = self._validate(np.array([[row, col]], dtype=np.int64), "SET_PIXEL")
        self._transact(p.Cmd.SET_PIXEL, p.encode_set_pixel(int(px[0, 0]), int(px[0, 1])))

    def upload_pattern(self, pixels: np.ndarray) -> int:
        """Validate and upload a scan pattern of (row, col) pixels; returns the chunk count.

        PATTERN_BEGIN carries the CRC-32 of the whole pattern, every PATTERN_CHUNK its own
        CRC-32, and PATTERN_END makes the FPGA check both (NAK PATTERN_CRC otherwise).
        """
        px = self._validate(pixels, "pattern")
        data = p.pack_pixels(px)
        n = px.shape[0]
        self._transact(p.Cmd.PATTERN_BEGIN, p.encode_pattern_begin(n, p.crc32(data)))
        chunks = 0
        size = self.chunk_pixels
        off = 0
        while off < n:
            part = data[2 * off: 2 * min(n, off + size)]
            try:
                self._transact(p.Cmd.PATTERN_CHUNK, p.encode_pattern_chunk(off, part))
            except (LinkError, DeviceTimeout):
                # A noisy line corrupts long frames far more often than short ones (P(ok) falls
                # exponentially with the length): halve the chunk and resend the same offset.
                if size <= _MIN_CHUNK_PIXELS:
                    raise
                size = max(_MIN_CHUNK_PIXELS, size // 2)
                log.warning("%s: PATTERN_CHUNK at %d failed; retrying with %d-pixel chunks",
                            self.device, off, size)
                continue
            off += len(part) // 2
            chunks += 1
        self._transact(p.Cmd.PATTERN_END)
        return chunks

    def set_timing(self, timing: p.Timing | None = None, *, settle_ns: int | None = None,
                   dwell_ns: int | None = None, triggers_per_pixel: int | None = None,
                   trigger_period_ns: int | None = None) -> p.Timing:
        """Set the per-pixel schedule; unspecified fields keep the protocol defaults."""
        base = timing or p.DEFAULT_TIMING
        t = p.Timing(
            settle_ns=base.settle_ns if settle_ns is None else settle_ns,
            dwell_ns=base.dwell_ns if dwell_ns is None else dwell_ns,
            triggers_per_pixel=(base.triggers_per_pixel if triggers_per_pixel is None
                                else triggers_per_pixel),
            trigger_period_ns=(base.trigger_period_ns if trigger_period_ns is None
                               else trigger_period_ns),
        )
        try:
            payload = t.pack()
        except ProtocolError as exc:
            raise InvalidValue(self.device, "SET_TIMING", f"{self.device}: {exc}") from exc
        if t.triggers_per_pixel < 1:
            raise InvalidValue(self.device, "SET_TIMING", f"{self.device}: triggers_per_pixel must be >= 1")
        self._transact(p.Cmd.SET_TIMING, payload)
        return t

    def arm(self) -> None:
        self._transact(p.Cmd.ARM)

    def start(self) -> None:
        self._transact(p.Cmd.START)

    def stop(self) -> None:
        self._transact(p.Cmd.STOP)

    def status(self) -> p.Status:
        return p.Status.unpack(self._transact(p.Cmd.STATUS))


def _close(channel: ByteChannel) -> None:
    """Close a channel that has ``close()`` (an optional extra of :class:`ByteChannel`)."""
    close = getattr(channel, "close", None)
    if close is not None:
        close()
