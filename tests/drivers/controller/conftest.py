"""Fixtures: a simulated controller on 127.0.0.1 (virtual clock) and a driver pointed at it."""

from __future__ import annotations

import pytest

from drivers.controller import protocol as p
from drivers.controller.driver import LaserHvController, SettleCheck
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim
from tests.helpers.deadlines import REPLY_S

# Deployment limits tighter than the hardware's (250 mA, 100 V, 15..40 degC).
LIMITS = p.Limits(max_laser_current_ma=200.0, max_hv_v=60.0, tec_range_c=(18.0, 35.0))
# Wider than the hardware: lets a test push out-of-range values past the driver to the device.
WIDE = p.Limits(max_laser_current_ma=600.0, max_hv_v=600.0, tec_range_c=(-100.0, 300.0))
# Replies from the local simulator take ~0.1 ms, so a generous timeout costs nothing unless a reply
# is really lost (tests/helpers/deadlines.py); tests that lose replies on purpose use FAST_TIMEOUT_S
# (each loss waits that long), long enough that a reply that is only late (a loaded machine: tens of
# ms) is not taken for a lost one and retried, which would change the counts they assert.
TIMEOUT_S = REPLY_S
FAST_TIMEOUT_S = 0.5


@pytest.fixture
def clock():
    return VirtualClock()


@pytest.fixture
def sim(clock):
    s = ControllerSim(clock)
    s.start()
    yield s
    s.stop()


@pytest.fixture
def ctl(sim):
    c = LaserHvController("127.0.0.1", sim.port, device_id=1, timeout_s=TIMEOUT_S, retries=2,
                          limits=LIMITS)
    yield c
    c.close()


@pytest.fixture
def wide(sim):
    c = LaserHvController("127.0.0.1", sim.port, timeout_s=TIMEOUT_S, retries=0, limits=WIDE)
    yield c
    c.close()


@pytest.fixture
def fast(sim):
    """Driver with a short timeout, for tests that drop replies on purpose."""
    c = LaserHvController("127.0.0.1", sim.port, timeout_s=FAST_TIMEOUT_S, retries=2, limits=LIMITS)
    yield c
    c.close()


@pytest.fixture
def settle(clock):
    return SettleCheck(sleep=clock.advance, timeout_s=20.0, poll_s=0.005)
