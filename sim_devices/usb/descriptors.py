"""What pyusb reads of a simulated USB device: its descriptors, and the descriptor half of a pyusb
backend (§4.4.1: the AWG and the ADC hang off the PC's USB bus).

A simulated device states its identity as a :class:`DeviceSpec` (VID/PID, strings, one interface,
its bulk endpoints); pyusb reads descriptor fields with getattr(), so the builders return plain
attribute bags. :class:`_DescriptorBackend` serves them (device, configuration, interface and
endpoint descriptors, configuration and claim bookkeeping) for both the in-process backend
(``sim_devices.usb.backend.SimUsbBackend``) and the one across processes
(``sim_devices.usb.bridge.RemoteUsbBackend``); the transfers are theirs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import usb.backend

from sim_devices.usb.errors import usb_stall


class _Desc:
    """Plain attribute bag: pyusb reads descriptor fields with getattr()."""

    def __init__(self, **fields: object) -> None:
        self.__dict__.update(fields)


@dataclass(frozen=True)
class EndpointSpec:
    address: int
    attributes: int = 0x02  # bulk
    max_packet: int = 512


@dataclass(frozen=True)
class DeviceSpec:
    """What a device says about itself in its descriptors."""

    vid: int
    pid: int
    manufacturer: str
    product: str
    serial: str
    interface_class: int
    interface_subclass: int
    interface_protocol: int
    endpoints: tuple[EndpointSpec, ...]

    def to_json(self) -> dict:
        d = self.__dict__.copy()
        d["endpoints"] = [e.__dict__ for e in self.endpoints]
        return d

    @staticmethod
    def from_json(d: dict) -> DeviceSpec:
        d = dict(d)
        d["endpoints"] = tuple(EndpointSpec(**e) for e in d["endpoints"])
        return DeviceSpec(**d)


def _device_descriptor(spec: DeviceSpec, bus: int, address: int) -> _Desc:
    return _Desc(bLength=18, bDescriptorType=1, bcdUSB=0x0200, bDeviceClass=0, bDeviceSubClass=0,
                 bDeviceProtocol=0, bMaxPacketSize0=64, idVendor=spec.vid, idProduct=spec.pid,
                 bcdDevice=0x0100, iManufacturer=1, iProduct=2, iSerialNumber=3,
                 bNumConfigurations=1, address=address, bus=bus, port_number=address,
                 port_numbers=(address,), speed=3)  # 3 = high speed (480 Mbit/s)


def _config_descriptor(spec: DeviceSpec) -> _Desc:
    return _Desc(bLength=9, bDescriptorType=2, wTotalLength=9 + 9 + 7 * len(spec.endpoints),
                 bNumInterfaces=1, bConfigurationValue=1, iConfiguration=0, bmAttributes=0x80,
                 bMaxPower=250, extra_descriptors=[])


def _interface_descriptor(spec: DeviceSpec) -> _Desc:
    return _Desc(bLength=9, bDescriptorType=4, bInterfaceNumber=0, bAlternateSetting=0,
                 bNumEndpoints=len(spec.endpoints), bInterfaceClass=spec.interface_class,
                 bInterfaceSubClass=spec.interface_subclass,
                 bInterfaceProtocol=spec.interface_protocol, iInterface=0, extra_descriptors=[])


def _endpoint_descriptor(ep: EndpointSpec) -> _Desc:
    return _Desc(bLength=7, bDescriptorType=5, bEndpointAddress=ep.address,
                 bmAttributes=ep.attributes, wMaxPacketSize=ep.max_packet, bInterval=0,
                 bRefresh=0, bSynchAddress=0, extra_descriptors=[])


def _string_descriptor(text: str) -> bytes:
    raw = text.encode("utf-16-le")
    return bytes((2 + len(raw), 3)) + raw


class _SimHandle:
    __slots__ = ("index", "open", "config")

    def __init__(self, index: int) -> None:
        self.index = index
        self.open = True
        self.config = 1


class _DescriptorBackend(usb.backend.IBackend):
    """Descriptor half shared by the in-process and remote backends (device id = index)."""

    def _specs(self) -> Sequence[DeviceSpec]:
        raise NotImplementedError

    def _spec(self, dev: int) -> DeviceSpec:
        return self._specs()[dev]

    def get_device_descriptor(self, dev):
        return _device_descriptor(self._spec(dev), bus=1, address=dev + 2)

    def get_configuration_descriptor(self, dev, config):
        if config != 0:
            raise IndexError(f"configuration index {config} (device has one)")
        return _config_descriptor(self._spec(dev))

    def get_interface_descriptor(self, dev, intf, alt, config):
        if config != 0 or intf != 0 or alt != 0:
            raise IndexError(f"interface ({intf},{alt}) of config {config}")
        return _interface_descriptor(self._spec(dev))

    def get_endpoint_descriptor(self, dev, ep, intf, alt, config):
        spec = self._spec(dev)
        if config != 0 or intf != 0 or alt != 0 or not 0 <= ep < len(spec.endpoints):
            raise IndexError(f"endpoint {ep} of interface ({intf},{alt})")
        return _endpoint_descriptor(spec.endpoints[ep])

    def get_parent(self, dev):
        return None

    def set_configuration(self, dev_handle, config_value):
        if config_value not in (0, 1):
            raise usb_stall(f"set_configuration({config_value})")
        dev_handle.config = config_value

    def get_configuration(self, dev_handle):
        return dev_handle.config

    def set_interface_altsetting(self, dev_handle, intf, altsetting):
        if intf != 0 or altsetting != 0:
            raise usb_stall(f"set_interface_altsetting({intf},{altsetting})")

    def claim_interface(self, dev_handle, intf):
        if intf != 0:
            raise usb_stall(f"claim_interface({intf})")

    def release_interface(self, dev_handle, intf):
        pass

    def is_kernel_driver_active(self, dev_handle, intf):
        return False

    def detach_kernel_driver(self, dev_handle, intf):
        pass

    def attach_kernel_driver(self, dev_handle, intf):
        pass
