"""Fixtures of the offline (Dask sweep) tests: an in-process LocalCluster, a small sweep builder."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def client():
    """A LocalCluster of 2 worker THREADS in this process (no process spawn: fast and small)."""
    from lidard.offline.cluster import open_client
    with open_client(n_workers=2, processes=False) as c:
        yield c


@pytest.fixture
def make_sweep():
    """sweep dict on the packaged sim.toml: the given grid, 2 distances, 2 seeds, 4 trials per task."""
    def build(grid: dict | None = None, *, seeds=2, trials=4, distances=(3.0, 12.0), **target) -> dict:
        return {"sweep": {"name": "t", "base_config": "sim.toml", "seeds": seeds, "trials_per_task": trials},
                "grid": {"scan.max_range_m": 15.0, **(grid or {})},
                "target": {"distances_m": list(distances), **target}}
    return build
