"""Fixtures: a simulated digitizer with a deterministic tone source, reached through pyusb."""

import numpy as np
import pytest
import usb.core

from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDriver
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import RemoteUsbBackend, SimUsbBackend, UsbBridgeServer

TRIGGER_PERIOD_S = 100e-6


class ToneSource:
    """Segment k: channel c is a tone of (k+1)*1 MHz + c*100 kHz, amplitude ``amp`` codes;
    trigger k at k*100 us; segments listed in ``over`` are flagged overrange on channel 0."""

    def __init__(self, amp: int = 1000, over: tuple[int, ...] = ()) -> None:
        self.amp = amp
        self.over = set(over)
        self.calls: list[tuple[int, int]] = []

    def expected(self, first, count, cfg):
        idx = np.arange(first, first + count)
        t = np.arange(cfg.record_length) / cfg.sample_rate_hz
        n_ch = len(cfg.channels)
        codes = np.empty((count, n_ch, cfg.record_length), dtype=np.int16)
        for c in range(n_ch):
            f = (idx[:, None] + 1) * 1e6 + c * 1e5
            codes[:, c, :] = np.rint(self.amp * np.sin(2 * np.pi * f * t))
        over = np.zeros((count, n_ch), dtype=bool)
        for k in self.over:
            if first <= k < first + count:
                over[k - first, 0] = True
        return idx * TRIGGER_PERIOD_S, codes, over

    def capture(self, first, count, cfg):
        self.calls.append((first, count))
        t, codes, over = self.expected(first, count, cfg)
        return CapturedSegments(t, codes, over)


@pytest.fixture(params=["inproc", "bridge"])
def dig_rig(request):
    """(driver, sim, source, clock) for both backend modes."""
    clock = VirtualClock()
    src = ToneSource(over=(2,))
    sim = SimDigitizer(clock, src, batch_bytes=64 * 1024)
    if request.param == "inproc":
        backend, server = SimUsbBackend([sim]), None
    else:
        server = UsbBridgeServer([sim])
        backend = RemoteUsbBackend(f"tcp://127.0.0.1:{server.port}")
    dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=backend)
    assert dev is not None
    yield DigitizerDriver(dev, timeout_ms=200, retries=2, chunk_bytes=48 * 1024), sim, src, clock
    if server is not None:
        backend.close()
        server.close()
