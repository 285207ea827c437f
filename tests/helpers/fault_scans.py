"""Scans through a job worker, each after the next fault of a cycle (as benchmarks/soak.py drives a
daemon), for the memory tests that compare whole cycles."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class FaultCycle:
    """``scan()`` injects the next fault of ``faults`` (None: no fault), runs one ``request`` through
    ``worker``, clears the faults and requires the scan to end done. ``during(record)``, if given, runs
    once the scan is submitted and may return a function called after it ends."""

    def __init__(self, inst: Any, worker: Any, faults: list, request: Any, timeout_s: float) -> None:
        self.inst, self.worker, self.faults = inst, worker, faults
        self.request, self.timeout_s, self.k = request, timeout_s, 0

    def scan(self, during: Callable[[Any], Callable[[], None] | None] | None = None) -> None:
        fault = self.faults[self.k % len(self.faults)]
        self.k += 1
        if fault is not None:
            self.inst.inject_fault(fault[0], **fault[1])
        rec = self.worker.submit_scan(self.request)
        after = during(rec) if during is not None else None
        final = self.worker.wait(rec.id, timeout_s=self.timeout_s)
        if after is not None:
            after()
        self.inst.clear_faults()
        assert final.state == "done", (fault, final.state, final.error)
