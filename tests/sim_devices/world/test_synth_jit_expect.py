"""The synthesis' compiled kernels are loaded by the size of the acquisition the simulated digitizer is
armed for (sim_devices.world.synth_jit.expect), so a scan past the break-even runs compiled from its
first read. In a fresh interpreter each: the decision is per process, and numba must not be loaded."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_ARM = """
import sys
import usb.core
from drivers.digitizer import protocol as dp
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import SimDigitizer
from sim_devices.usb.backend import SimUsbBackend
from sim_devices.world import synth_jit

assert "numba" not in sys.modules
dev = usb.core.find(idVendor=dp.DIGITIZER_VID, idProduct=dp.DIGITIZER_PID,
                    backend=SimUsbBackend([SimDigitizer(VirtualClock(), None)]))
dev.ctrl_transfer(0x40, 0x10, 0x01, 0, None)                      # one channel
dev.ctrl_transfer(0x40, 0x12, 0, 0, dp.enc_u32(1190))             # the default band's records
dev.ctrl_transfer(0x40, 0x13, 0, 0, dp.enc_u32({segments}))
dev.ctrl_transfer(0x40, 0x20, 0, 0, None)                         # ARM
print("compiled" if synth_jit.quantize_rows(1000, noisy=True) is not None else "numpy")
"""


@pytest.mark.parametrize("segments, path", [
    (40_000, "compiled"),      # 47.6 M noisy samples: past the break-even (0.9 s / 25 ns = 36 M)
    (160, "numpy"),            # a 16-pixel scan at 10 averages: 0.19 M, the numpy path (no numba load)
])
def test_arming_decides_the_kernels_by_the_acquisition_size(segments, path):
    out = subprocess.run([sys.executable, "-c", _ARM.format(segments=segments)], capture_output=True, text=True,
                         timeout=300, env={**os.environ, "LIDARD_DSP_JIT": "1"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.split()[-1] == path
