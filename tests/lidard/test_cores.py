"""The workers a process's pools get (lidard.cores): one per core of the process's CPU affinity, not
of the machine, at most 4; the DSP's processes and threads and the bench's synthesis threads all
follow the same count."""

import os

import pytest

from lidard import cores, dsp_pool
from lidard.instrument import scan_loop
from sim_devices.world import synth_parallel


def _pools() -> dict[str, int]:
    return {"DSP processes": dsp_pool.pool_workers(), "DSP threads": scan_loop.pool_workers(),
            "synthesis threads": synth_parallel.synth_threads()}


@pytest.mark.parametrize("affinity, machine, expected", [
    ({0}, 8, 1),                   # pinned to one core on an 8-core machine: one, not eight
    ({2, 5}, 8, 2),
    (set(range(16)), 16, 4),       # capped
])
def test_the_pools_follow_the_process_affinity(monkeypatch, affinity, machine, expected):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: affinity)
    monkeypatch.setattr(os, "cpu_count", lambda: machine)
    assert cores.usable_cores() == len(affinity)
    assert _pools() == dict.fromkeys(_pools(), expected)


def test_without_an_affinity_the_machines_cores_count(monkeypatch):
    monkeypatch.delattr(os, "sched_getaffinity")
    monkeypatch.setattr(os, "cpu_count", lambda: 3)
    assert cores.usable_cores() == 3 and _pools() == dict.fromkeys(_pools(), 3)
    monkeypatch.setattr(os, "cpu_count", lambda: None)     # unknown: one
    assert cores.usable_cores() == 1 and _pools() == dict.fromkeys(_pools(), 1)
