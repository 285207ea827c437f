"""Finding a USB instrument again after it was unplugged: the one loop both USB drivers use.

A replugged device is a new pyusb ``Device``: look it up again through ``finder`` (VID:PID on the
driver's backend), the looks spaced by the driver's :class:`drivers.retry.RetryPolicy` (bounded,
exponential backoff on the injected clock), and set its configuration.
"""

from __future__ import annotations

from collections.abc import Callable

import usb.core

from drivers.retry import RetryPolicy
from drivers.usbtmc import DeviceDisconnected, classify_usb_error


def refind_device(finder: Callable[[], usb.core.Device | None] | None, *, device: str, command: str,
                  policy: RetryPolicy) -> usb.core.Device:
    """The configured device, found again; :class:`DeviceDisconnected` naming ``device`` and
    ``command`` if it is not back after ``policy.attempts`` looks (``policy``'s backoff between)."""
    if finder is None:
        raise DeviceDisconnected(device, command, "device disconnected and no finder to look for it")
    cause = "not found on the bus"
    for _ in policy.tries():
        try:
            dev = finder()
            if dev is None:
                continue
            dev.set_configuration()
        except usb.core.USBError as exc:
            cause = str(classify_usb_error(exc, device, "set_configuration"))
            continue
        return dev
    raise DeviceDisconnected(device, command, f"device gone and not back after {policy.attempts} looks ({cause})")
