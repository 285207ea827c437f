"""Wire tracing as a wrapper around a byte channel (the idea of pyserial's ``spy://``).

Drivers never print: wrapping the channel in :class:`TracedChannel` logs every transmitted
write and every received frame as a hex dump through :mod:`logging` (logger
``drivers.transport.wire`` by default, level DEBUG), so tracing is switched on by configuration
and costs nothing when off.
"""

from __future__ import annotations

import logging
from typing import Any

WIRE_LOGGER = logging.getLogger("drivers.transport.wire")


def hexdump(data: bytes, *, limit: int = 96) -> str:
    """Space-separated hex bytes, elided after ``limit`` bytes (a long pattern chunk stays readable)."""
    shown = data[:limit].hex(" ")
    if len(data) > limit:
        shown += f" ... (+{len(data) - limit} bytes)"
    return shown


class TracedChannel:
    """Delegates to a serial-like ``inner`` channel and logs the bytes that cross it.

    ``delimiter`` lets received bytes be logged one frame at a time (bytes are accumulated until
    the delimiter arrives) instead of one ``read()`` call at a time, which is what a human reading
    a trace wants. Writes are logged per call: drivers write one frame per call.
    """

    def __init__(
        self,
        inner: Any,
        *,
        device: str = "device",
        delimiter: bytes | None = b"\x00",
        logger: logging.Logger | None = None,
    ) -> None:
        self._inner = inner
        self._device = device
        self._delimiter = delimiter
        self._log = logger or WIRE_LOGGER
        self._rx_pending = bytearray()

    # --- the serial-like surface the drivers use -------------------------------------------
    def write(self, data: bytes) -> int | None:
        if self._log.isEnabledFor(logging.DEBUG):
            self._log.debug("%s TX %d B: %s", self._device, len(data), hexdump(bytes(data)))
        return self._inner.write(data)

    def read(self, size: int = 1) -> bytes:
        data = self._inner.read(size)
        if data and self._log.isEnabledFor(logging.DEBUG):
            self._log_rx(bytes(data))
        return data

    def _log_rx(self, data: bytes) -> None:
        if self._delimiter is None:
            self._log.debug("%s RX %d B: %s", self._device, len(data), hexdump(data))
            return
        self._rx_pending += data
        while True:
            end = self._rx_pending.find(self._delimiter)
            if end < 0:
                break
            frame = bytes(self._rx_pending[: end + len(self._delimiter)])
            del self._rx_pending[: end + len(self._delimiter)]
            self._log.debug("%s RX %d B: %s", self._device, len(frame), hexdump(frame))

    def __getattr__(self, name: str) -> Any:
        # timeout, in_waiting, reset_input_buffer, close, ... pass straight through.
        return getattr(self._inner, name)

    def __setattr__(self, name: str, value: Any) -> None:
        if name.startswith("_"):
            object.__setattr__(self, name, value)
        else:
            setattr(self._inner, name, value)

    def close(self) -> None:
        if self._rx_pending:
            self._log.debug(
                "%s RX (unterminated) %d B: %s", self._device, len(self._rx_pending),
                hexdump(bytes(self._rx_pending)),
            )
            self._rx_pending.clear()
        self._inner.close()
