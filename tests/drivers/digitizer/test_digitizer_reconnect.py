"""Digitizer and AWG drivers re-find their USB device (VID:PID) after a disconnect."""

import numpy as np
import pytest
import usb.core

from drivers.awg import protocol as awg_p
from drivers.awg.driver import AwgDriver
from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDriver
from drivers.usbtmc import DeviceDisconnected
from sim_devices.awg.device import SimAwg
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import SimDigitizer
from sim_devices.usb.backend import SimUsbBackend

from .conftest import ToneSource


def _rig():
    clock = VirtualClock()
    src = ToneSource()
    sim = SimDigitizer(clock, src, batch_bytes=64 * 1024)
    backend = SimUsbBackend([sim])

    def find():
        return usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=backend)
    return sim, src, find


def test_disconnect_is_healed_by_finding_the_device_again():
    sim, src, find = _rig()
    slept = []
    drv = DigitizerDriver(find(), timeout_ms=200, retries=2, finder=find, sleep=slept.append)
    sim.disconnect(transfers=1)               # unplugged; back after one failed transfer
    ident = drv.identify()
    s = sim.spec                              # answered after the re-find, by the same device
    assert ident == f"{s.manufacturer},{s.product},{s.serial},1.0"
    assert drv.reconnect_count == 1


def test_device_that_stays_away_raises_disconnected_after_bounded_looks():
    sim, src, find = _rig()
    slept = []
    drv = DigitizerDriver(find(), timeout_ms=200, retries=2, finder=find, sleep=slept.append, backoff_s=0.01)
    sim.disconnect()                          # gone from the bus until reconnect()
    with pytest.raises(DeviceDisconnected, match="digitizer") as ei:
        drv.identify()
    assert "not back after 3 looks" in str(ei.value)
    assert slept == pytest.approx([0.01, 0.02])
    sim.reconnect()
    drv.reconnect()
    assert drv.identify()


def test_without_a_finder_a_disconnect_is_raised_at_once():
    sim, src, find = _rig()
    drv = DigitizerDriver(find(), timeout_ms=200, retries=2)
    sim.inject_fault("disconnect")
    with pytest.raises(DeviceDisconnected):
        drv.identify()


def test_settings_survive_a_replug_and_the_driver_keeps_working():
    sim, src, find = _rig()
    drv = DigitizerDriver(find(), timeout_ms=200, retries=2, finder=find, sleep=lambda s: None)
    cfg = drv.configure(channels=("beat",), sample_rate_hz=10e6, record_length=256, segments=8, bits=16)
    sim.disconnect(transfers=1)
    assert drv.config() == cfg                 # re-found, and the configuration is still there
    drv.arm()
    _, got = drv.read_segments(0, 4, cfg)
    assert np.array_equal(got, src.expected(0, 4, cfg)[1])


def test_awg_re_finds_its_device_and_resends_the_command():
    awg = SimAwg()
    backend = SimUsbBackend([awg])

    def find():
        return usb.core.find(idVendor=awg_p.AWG_VID, idProduct=awg_p.AWG_PID, backend=backend)
    drv = AwgDriver(find(), timeout_ms=200, retries=2, finder=find, sleep=lambda s: None)
    awg.disconnect(transfers=1)
    drv.set_sample_rate(100e6)
    assert drv.sample_rate() == pytest.approx(100e6)
    assert drv.reconnect_count == 1
