"""Byte channels for serial-style instruments: open by URL, trace the wire, typed errors."""

from .channel import SCHEMES, ByteChannel, Scheme, open_channel
from .errors import DeviceTimeout, TransportError
from .trace import TracedChannel, hexdump

__all__ = [
    "SCHEMES",
    "ByteChannel",
    "DeviceTimeout",
    "Scheme",
    "TracedChannel",
    "TransportError",
    "hexdump",
    "open_channel",
]
