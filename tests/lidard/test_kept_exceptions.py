"""A failed job's exception outlives its handler in the job's future (the API reads it from there), and
a kept traceback keeps every frame it passed through, with their arrays: a failed linearization's MZI
records are megabytes. The handler's frame also holds the job, the job its future and the future the
exception: a reference cycle, so those frames and arrays stayed until the cyclic collector's next full
collection, minutes apart in a long-running daemon (the soak's RSS moved in steps of about 5 MB).

As in tests/lidard/test_memory_per_scan.py, the window runs with the cyclic collector off: what only a
collection would free counts as held. The failing procedure allocates its records, then fails with a
chained error (a device fault under it), as a driver failure inside a calibration does."""

from __future__ import annotations

import gc
import weakref
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from lidard.jobs import ScanWorker
from lidard.store import Store
from tests.helpers.deadlines import WAIT_S
from tests.helpers.fakes import DeviceFault, FakeInstrument


def _failing(kept: list[weakref.ref]) -> Callable[..., Any]:
    def procedure(progress=None):
        records = np.ones((64, 4096))        # 2 MB: a health check's MZI records
        kept.append(weakref.ref(records))
        try:
            raise DeviceFault("digitizer: no answer to READ_SEGMENTS")
        except DeviceFault as exc:
            raise RuntimeError(f"linearization stopped after {records.shape[0]} records") from exc
    return procedure


@pytest.fixture
def worker(tmp_path):
    inst = FakeInstrument()
    w = ScanWorker(inst, Store(tmp_path / "data"), laser="dfb_default", progress_interval_s=0.0)
    w.start()
    yield inst, w
    w.stop()


@pytest.mark.parametrize("kind", ["calibration", "selftest", "task"])
def test_a_failed_jobs_future_does_not_keep_the_frames_and_arrays_of_the_failure(worker, kind):
    inst, w = worker
    kept: list[weakref.ref] = []
    procedure = _failing(kept)
    if kind == "calibration":
        inst.linearize = procedure
        submit = w.submit_calibration
    elif kind == "selftest":
        inst.selftest = procedure
        submit = w.submit_selftest
    else:
        def submit():
            return w.submit_task(procedure)
    gc.collect()
    gc.disable()
    try:
        fut = submit()
        exc = fut.exception(timeout=WAIT_S)
        # the caller still learns what failed and why
        assert type(exc) is RuntimeError and "after 64 records" in str(exc)
        assert isinstance(exc.__cause__, DeviceFault) and "READ_SEGMENTS" in str(exc.__cause__)
        w.submit_task(lambda: None).result(timeout=WAIT_S)   # the failed job's handler has returned
        del fut, exc
        held = len(kept) == 1 and kept[0]() is not None
    finally:
        gc.enable()
    assert len(kept) == 1
    assert not held, f"the failed {kind}'s records are still held after its future was dropped"
