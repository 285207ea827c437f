"""Controller driver under faults: busy answers retried with backoff, lost connections reconnected."""

import pytest

from drivers.controller.driver import LaserHvController
from drivers.controller.errors import DeviceBusy, DeviceUnreachable
from sim_devices.clock import VirtualClock
from sim_devices.controller.device import ControllerSim

from .conftest import LIMITS, TIMEOUT_S


def test_busy_answers_are_retried_with_exponential_backoff(sim):
    slept = []
    c = LaserHvController("127.0.0.1", sim.port, timeout_s=TIMEOUT_S, limits=LIMITS, busy_retries=3,
                          sleep=slept.append, backoff_s=0.01)
    sim.inject_exception(6, 3)                 # SERVER DEVICE BUSY three times, then normal
    assert c.tec_c() == pytest.approx(25.0)
    assert slept == pytest.approx([0.01, 0.02, 0.04])
    c.close()


def test_busy_beyond_the_budget_is_raised_typed(sim):
    c = LaserHvController("127.0.0.1", sim.port, timeout_s=TIMEOUT_S, limits=LIMITS, busy_retries=1,
                          sleep=lambda s: None)
    sim.inject_exception(6, 2)
    with pytest.raises(DeviceBusy):
        c.tec_c()
    assert c.tec_c() == pytest.approx(25.0)    # the budget is per request
    c.close()


def test_other_exceptions_are_never_retried(sim):
    slept = []
    c = LaserHvController("127.0.0.1", sim.port, timeout_s=TIMEOUT_S, limits=LIMITS, busy_retries=3,
                          sleep=slept.append)
    received = sim.requests_received
    sim.inject_exception(4, 1)
    with pytest.raises(Exception, match="exception 4"):
        c.tec_c()
    assert slept == [] and sim.requests_received - received == 1
    c.close()


def test_driver_reconnects_after_the_server_comes_back_on_the_same_port():
    clock = VirtualClock()
    first = ControllerSim(clock)
    first.start()
    port = first.port
    slept = []
    c = LaserHvController("127.0.0.1", port, timeout_s=TIMEOUT_S, retries=2, limits=LIMITS,
                          sleep=slept.append, backoff_s=0.01)
    assert c.tec_c() == pytest.approx(25.0)
    first.stop()                               # the controller is power-cycled
    with pytest.raises(DeviceUnreachable, match=f"127.0.0.1:{port}"):
        c.tec_c()
    assert slept == pytest.approx([0.01, 0.02])   # bounded: retries=2 -> 3 attempts, 2 backoffs
    second = ControllerSim(clock, port=port)
    second.start()
    try:
        assert c.tec_c() == pytest.approx(25.0)    # no new driver object: it reconnected
        assert c.reconnect_count >= 1
    finally:
        c.close()
        second.stop()
