"""A pyusb backend that carries USB transfers to the simulated devices, in-process or over a bridge."""

from sim_devices.usb.backend import SimUsbBackend, backend_from_url
from sim_devices.usb.bridge import RemoteUsbBackend, UsbBridgeServer
from sim_devices.usb.descriptors import DeviceSpec, EndpointSpec
from sim_devices.usb.device import SimUsbDevice

__all__ = ["DeviceSpec", "EndpointSpec", "RemoteUsbBackend", "SimUsbBackend", "SimUsbDevice",
           "UsbBridgeServer", "backend_from_url"]
