"""Fixtures: a simulated AWG reached through real pyusb calls, in-process or over the TCP bridge."""

import pytest
import usb.core

from drivers.awg import protocol as p
from drivers.awg.driver import AwgDriver
from sim_devices.awg.device import SimAwg
from sim_devices.usb.backend import RemoteUsbBackend, SimUsbBackend, UsbBridgeServer


@pytest.fixture(params=["inproc", "bridge"])
def awg_pair(request):
    """(driver, simulated device) for both backend modes."""
    sim = SimAwg()
    if request.param == "inproc":
        backend = SimUsbBackend([sim])
        server = None
    else:
        server = UsbBridgeServer([sim])
        backend = RemoteUsbBackend(f"tcp://127.0.0.1:{server.port}")
    dev = usb.core.find(idVendor=p.AWG_VID, idProduct=p.AWG_PID, backend=backend)
    assert dev is not None
    yield AwgDriver(dev, timeout_ms=200, retries=2), sim
    if server is not None:
        backend.close()
        server.close()
