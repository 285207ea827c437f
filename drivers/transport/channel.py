"""Open a byte channel to an instrument from a URL (device path, pty, TCP, loopback).

Follows pyserial's URL idea: the same driver talks to a lab device on ``/dev/ttyUSB1``, to the
simulated FPGA on a pty path (``/dev/pts/7``), to a bench over ``socket://127.0.0.1:5020``, or to
a loopback ``loop://`` by changing one configuration string. Unlike pyserial we keep an explicit,
immutable scheme table here and never touch ``serial.protocol_handler_packages``: an unknown
scheme is a :class:`TransportError` naming the URL, not a silent import attempt.

``trace+<url>`` (or ``trace=True``) wraps the channel in :class:`TracedChannel` so every frame
is hex-dumped through :mod:`logging`.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Protocol, runtime_checkable

import serial

from .errors import DeviceGone, TransportError
from .trace import TracedChannel

TRACE_PREFIX = "trace+"


@runtime_checkable
class ByteChannel(Protocol):
    """The byte seam every serial-style driver talks through (pyserial's ``Serial`` API, minimal).

    ``read(size)`` returns up to ``size`` bytes and returns early (possibly with none) when
    ``timeout`` seconds pass, which is how a driver detects a silent device; ``write`` sends all
    of ``data``. A ``serial.Serial`` from :func:`open_channel`, the simulator's in-memory pipe and
    a test's fault-injecting wrapper all satisfy it. Optional extras a driver uses when present:
    ``in_waiting`` (read what is buffered in one call) and ``close()`` (called only on channels
    the driver opened itself).
    """

    timeout: float | None

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...


@dataclass(frozen=True)
class Scheme:
    """One supported URL scheme: what it is for, and whether the baud rate means anything."""

    description: str
    has_baudrate: bool


# Explicit table; "" is a plain path (serial device or pty). Add rows here, never at runtime.
SCHEMES: MappingProxyType[str, Scheme] = MappingProxyType(
    {
        "": Scheme("serial device or pty path, e.g. /dev/ttyUSB1", has_baudrate=True),
        "socket": Scheme("raw TCP, e.g. socket://127.0.0.1:5020", has_baudrate=False),
        "loop": Scheme("in-process loopback (echo), e.g. loop://", has_baudrate=False),
        "rfc2217": Scheme("remote serial port over telnet RFC 2217", has_baudrate=True),
    }
)


def split_scheme(url: str) -> tuple[str, str]:
    """Return (scheme, url) with any ``trace+`` prefix already removed by the caller."""
    if "://" in url:
        scheme = url.split("://", 1)[0].lower()
        return scheme, url
    return "", url


def open_channel(
    url: str,
    *,
    baudrate: int = 115_200,
    timeout_s: float = 0.5,
    write_timeout_s: float | None = 2.0,
    trace: bool = False,
    device: str = "device",
) -> ByteChannel:
    """Open ``url`` and return a serial-like channel (raises :class:`TransportError`).

    ``timeout_s`` is the read timeout: ``read(n)`` returns early with fewer bytes (possibly
    none) when it expires, which is how drivers detect a silent device.
    """
    if not isinstance(url, str) or not url:
        raise TransportError(device, "open", f"channel URL must be a non-empty string, got {url!r}")
    if url.startswith(TRACE_PREFIX):
        trace = True
        url = url[len(TRACE_PREFIX):]
    scheme, target = split_scheme(url)
    if scheme not in SCHEMES:
        known = ", ".join(f"{s}://" if s else "<path>" for s in SCHEMES)
        raise TransportError(device, "open", f"unknown URL scheme {scheme!r} (supported: {known})", url=url)
    if not baudrate > 0:
        raise TransportError(device, "open", f"baudrate must be > 0, got {baudrate!r}", url=url)
    try:
        port = serial.serial_for_url(
            target,
            baudrate=int(baudrate),
            timeout=timeout_s,
            write_timeout=write_timeout_s,
            do_not_open=False,
        )
    except (serial.SerialException, OSError, ValueError) as exc:
        raise DeviceGone(device, "open", f"cannot open: {exc}", url=url) from exc
    if trace:
        return TracedChannel(port, device=device)
    return port
