"""pyusb backends that carry the daemon's USB transfers to simulated instruments.

§4.4.1: the AWG and the ADC hang off the PC's USB bus. The daemon's drivers make ordinary pyusb
calls (``usb.core.find``, ``dev.set_configuration``, ``dev.write``, ``dev.read``,
``dev.ctrl_transfer``); which bus those calls reach is chosen by the backend the configuration
hands to ``usb.core.find``:

* lab:       ``usb.backend.libusb1.get_backend()`` (real hardware, libusb-1.0)
* in-process ``SimUsbBackend(devices=[awg, digitizer])``
* across processes: the bench runs ``UsbBridgeServer(devices)``; the daemon uses
  ``RemoteUsbBackend("tcp://127.0.0.1:PORT")``; framing in docs/protocols/usb_sim.md.

``backend_from_url`` maps a URL to one of these through an explicit scheme table.

Simulated devices subclass ``SimUsbDevice``: they provide descriptors and handle control, bulk-OUT
and bulk-IN transfers. USB failures are raised as pyusb's own exceptions (``USBTimeoutError``,
``USBError`` with errno EPIPE for a stall, ENODEV for a disconnected device) so the drivers exercise
the same error paths as on hardware; tests inject them with ``SimUsbDevice.inject_fault``.

Parts: this module is the in-process backend and the URL scheme table; the device base is
``sim_devices.usb.device``, its pyusb errors ``sim_devices.usb.errors``, the descriptors
``sim_devices.usb.descriptors``, the bridge across processes ``sim_devices.usb.bridge``.
"""

from __future__ import annotations

from collections.abc import Sequence
from urllib.parse import urlparse

import usb.backend

from sim_devices.usb.bridge import RemoteUsbBackend, UsbBridgeServer
from sim_devices.usb.descriptors import (
    DeviceSpec,
    EndpointSpec,
    _DescriptorBackend,
    _SimHandle,
)
from sim_devices.usb.device import FaultKind, FaultOp, SimUsbDevice
from sim_devices.usb.errors import usb_nodev, usb_stall, usb_timeout


class SimUsbBackend(_DescriptorBackend):
    """In-process backend: transfers become method calls on the device objects."""

    def __init__(self, devices: Sequence[SimUsbDevice]) -> None:
        super().__init__()
        self._devices = list(devices)

    def _specs(self) -> Sequence[DeviceSpec]:
        return [d.spec for d in self._devices]

    def enumerate_devices(self):
        return [i for i, d in enumerate(self._devices) if d.connected]

    def open_device(self, dev):
        self._devices[dev].usb_open()
        return _SimHandle(dev)

    def close_device(self, dev_handle):
        dev_handle.open = False

    def bulk_write(self, dev_handle, ep, intf, data, timeout):
        return self._devices[dev_handle.index].usb_bulk_out(ep, memoryview(data).cast("B"))

    def bulk_read(self, dev_handle, ep, intf, buff, timeout):
        return self._devices[dev_handle.index].usb_bulk_in(ep, memoryview(buff).cast("B"))

    def ctrl_transfer(self, dev_handle, bmRequestType, bRequest, wValue, wIndex, data, timeout):
        dev = self._devices[dev_handle.index]
        mv = memoryview(data).cast("B")
        if bmRequestType & 0x80:
            reply = dev.usb_ctrl(bmRequestType, bRequest, wValue, wIndex, None, len(mv))
            n = min(len(reply), len(mv))
            mv[:n] = reply[:n]
            return n
        return dev.usb_ctrl(bmRequestType, bRequest, wValue, wIndex, bytes(mv), len(mv))

    def clear_halt(self, dev_handle, ep):
        self._devices[dev_handle.index].usb_clear_halt(ep)

    def reset_device(self, dev_handle):
        self._devices[dev_handle.index].usb_reset()


# ----------------------------------------------------------------------------------- URLs


def _libusb1(_url: str, _devices: Sequence[SimUsbDevice] | None) -> usb.backend.IBackend:
    import usb.backend.libusb1

    backend = usb.backend.libusb1.get_backend()
    if backend is None:
        raise ValueError("libusb1:// requested but libusb-1.0 is not available on this host")
    return backend


def _inproc(url: str, devices: Sequence[SimUsbDevice] | None) -> usb.backend.IBackend:
    if devices is None:
        raise ValueError(f"{url!r} needs the simulated device objects (composition root only)")
    return SimUsbBackend(devices)


def _tcp(url: str, _devices: Sequence[SimUsbDevice] | None) -> usb.backend.IBackend:
    return RemoteUsbBackend(url)


_SCHEMES = {"libusb1": _libusb1, "sim-usb": _inproc, "sim-usb+tcp": _tcp}


def backend_from_url(url: str, devices: Sequence[SimUsbDevice] | None = None) -> usb.backend.IBackend:
    """``libusb1://`` (lab), ``sim-usb://inproc`` (needs ``devices``),
    ``sim-usb+tcp://HOST:PORT`` (a bench's UsbBridgeServer)."""
    scheme = urlparse(url).scheme
    try:
        factory = _SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"unknown USB backend URL scheme {scheme!r} in {url!r}; "
                         f"expected one of {sorted(_SCHEMES)}") from None
    if scheme == "sim-usb" and urlparse(url).netloc != "inproc":
        raise ValueError(f"sim-usb URL must be sim-usb://inproc, got {url!r}")
    return factory(url, devices)


__all__ = ["DeviceSpec", "EndpointSpec", "FaultKind", "FaultOp", "RemoteUsbBackend", "SimUsbBackend",
           "SimUsbDevice", "UsbBridgeServer", "backend_from_url", "usb_nodev", "usb_stall", "usb_timeout"]
