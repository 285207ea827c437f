"""A driver call that failed once and succeeded on its retry leaves no reference cycle behind.

A retry loop keeps the failed try's exception (to chain it if every try fails). Kept in a local of the
loop's frame after the loop returns, that exception's traceback holds the frame and the frame holds the
exception: a cycle only the cyclic collector frees. Python links a frame object that outlives its call
to its caller's frame, so the cycle pins every caller's frame and its locals (in the daemon: the
linearization health check's 5 MB of MZI records, the scan's batches) until a full collection, which in
a long-running daemon comes minutes apart (the soak's daemon RSS moved in 5.3 MB steps).

Checked here with the collector off: a caller's array must be freed by reference counting alone as soon
as the caller returns.
"""

from __future__ import annotations

import gc
import weakref
from collections.abc import Callable

import numpy as np
import pytest
import usb.core

from drivers.awg import protocol as awg_p
from drivers.awg.driver import AwgDriver
from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDriver
from sim_devices.awg.device import SimAwg
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import SimDigitizer
from sim_devices.usb.backend import SimUsbBackend

from .digitizer.conftest import ToneSource


def _digitizer() -> tuple[SimDigitizer, DigitizerDriver]:
    sim = SimDigitizer(VirtualClock(), ToneSource(), batch_bytes=64 * 1024)
    backend = SimUsbBackend([sim])

    def find():
        return usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=backend)
    return sim, DigitizerDriver(find(), timeout_ms=200, retries=2, finder=find, sleep=lambda s: None)


def _awg() -> tuple[SimAwg, AwgDriver]:
    sim = SimAwg()
    backend = SimUsbBackend([sim])

    def find():
        return usb.core.find(idVendor=awg_p.AWG_VID, idProduct=awg_p.AWG_PID, backend=backend)
    return sim, AwgDriver(find(), timeout_ms=200, retries=2, finder=find, sleep=lambda s: None)


def _caller_array_freed(call: Callable[[], object]) -> bool:
    """Whether an array local to the caller of ``call`` is freed when that caller returns (no collector)."""
    def caller() -> weakref.ref:
        held = np.zeros(1000)
        ref = weakref.ref(held)
        call()
        return ref
    was = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        ref = caller()
        return ref() is None
    finally:
        if was:
            gc.enable()


@pytest.mark.parametrize("fault", ["disconnect", "timeout"])
def test_digitizer_retry_leaves_no_cycle(fault):
    sim, drv = _digitizer()
    if fault == "disconnect":
        sim.disconnect(transfers=1)            # unplugged; back after one failed transfer
    else:
        sim.inject_fault("timeout")            # one transfer unanswered, the retry answered
    assert _caller_array_freed(drv.identify)
    assert drv.reconnect_count == (1 if fault == "disconnect" else 0)   # the retry path did run


def test_awg_retry_leaves_no_cycle():
    sim, drv = _awg()
    sim.disconnect(transfers=1)
    assert _caller_array_freed(lambda: drv.set_sample_rate(100e6))
    assert drv.reconnect_count == 1


def test_the_check_sees_a_kept_exception():
    """The control: a retry loop that keeps its exception (the old drivers' shape) fails the check."""
    def retried() -> int:
        last = None
        for attempt in range(2):
            try:
                if attempt == 0:
                    raise TimeoutError("first try")
                return attempt
            except TimeoutError as exc:
                last = exc
        raise AssertionError(last)
    assert not _caller_array_freed(retried)
