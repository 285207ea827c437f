"""The cores this process may run on, and the workers one of its pools gets from them.

One answer for every pool a process sizes by its cores: the frame DSP's worker processes
(:mod:`lidard.dsp_pool`) and threads (:mod:`lidard.instrument.pipeline`), and the simulated bench's
synthesis threads (:mod:`sim_devices.world.synth_parallel`). The count is the process's CPU affinity
(``taskset``, a container's cpuset), not the machine's: a process pinned to one core that started a
worker per machine core would only add their start-up and their contention.

Standard library only, so that the simulator (which imports no part of the daemon but the pure core)
and the daemon may both use it (pyproject.toml, [tool.importlinter]).
"""

from __future__ import annotations

import os

#: workers in one pool at most: beyond 4 a scan's pace is set by its read loop, not by the DSP or the
#: synthesis, and each worker holds its own scratch buffers
MAX_POOL_WORKERS = 4


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity where the platform has one, else the
    machine's count (at least 1)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def pool_workers() -> int:
    """Workers for one of this process's pools: one per core it may run on, at most
    :data:`MAX_POOL_WORKERS`."""
    return max(1, min(MAX_POOL_WORKERS, usable_cores()))
