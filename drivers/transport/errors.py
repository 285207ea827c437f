"""Typed errors of the byte-channel layer: the shared classes of :mod:`drivers.errors`.

Kept as a module so ``from drivers.transport.errors import DeviceTimeout`` keeps working; the
classes are the very ones in :mod:`drivers.errors` (not copies), so one ``except`` catches a
timeout of any device. Signature: ``TransportError(device, command, detail, url=...)``.
"""

from __future__ import annotations

from drivers.errors import DeviceGone, DeviceTimeout, TransportError

__all__ = ["DeviceGone", "DeviceTimeout", "TransportError"]
