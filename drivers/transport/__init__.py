"""Byte channels for serial-style instruments: the ByteChannel seam, open by URL, trace the wire.

Errors are the shared classes of :mod:`drivers.errors` (TransportError, DeviceTimeout, DeviceGone).
"""

from .channel import SCHEMES, ByteChannel, Scheme, open_channel
from .errors import DeviceGone, DeviceTimeout, TransportError
from .trace import TracedChannel, hexdump

__all__ = [
    "SCHEMES",
    "ByteChannel",
    "DeviceGone",
    "DeviceTimeout",
    "Scheme",
    "TracedChannel",
    "TransportError",
    "hexdump",
    "open_channel",
]
