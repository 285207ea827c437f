"""The failures of a simulated USB transfer, as the pyusb exceptions libusb-1.0 would raise: a timeout
(``USBTimeoutError``, errno ETIMEDOUT), a stall (``USBError`` errno EPIPE) and a device gone
(``USBError`` errno ENODEV), so the drivers run the same error paths as on hardware (§4.4.1).
"""

from __future__ import annotations

import errno

import usb.core


def usb_timeout(what: str) -> usb.core.USBTimeoutError:
    # libusb1 reports LIBUSB_ERROR_TIMEOUT (-7); pyusb maps it to errno ETIMEDOUT
    return usb.core.USBTimeoutError(f"Operation timed out ({what})", -7, errno.ETIMEDOUT)


def usb_stall(what: str) -> usb.core.USBError:
    return usb.core.USBError(f"Pipe error ({what})", -9, errno.EPIPE)


def usb_nodev(what: str) -> usb.core.USBError:
    return usb.core.USBError(f"No such device (it may have been disconnected) ({what})", -4,
                             errno.ENODEV)
