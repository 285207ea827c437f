"""A sweep task's DSP path is settled before its DSP: its figures do not depend on the worker that ran
it or on what that worker ran before (the tone fits' compiled and numpy paths agree only to rounding)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from lidard.dsp.spectrum import jit
from lidard.offline.spec import expand_sweep
from lidard.offline.sweep import task_frame
from tests.helpers.jit_ab import as_a_fresh_process

FIELDS = ("range_m", "velocity_mps", "intensity_v", "snr_db")


@pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed: one DSP path only")
def test_a_task_in_a_fresh_worker_takes_the_compiled_path_and_gives_the_same_results_again(monkeypatch):
    raw = {"sweep": {"seeds": 1, "trials_per_task": 2}, "grid": {"scan.max_range_m": 15.0},
           "target": {"distances_m": [3.0], "reflectivity": 0.5}}
    (task,) = expand_sweep(raw).tasks
    as_a_fresh_process(monkeypatch)      # nothing loaded, no cells counted (a small task stays below the count)
    first = task_frame(task).result
    # settled before the DSP ran: compiled, the path of a worker that had loaded the kernels before
    assert jit._compiled.cache_info().currsize == 1 and jit._asked[0] == 0
    again = task_frame(task).result
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(again, f), getattr(first, f), err_msg=f)
    assert np.nanmax(np.abs(first.range_m[:, 0] - 3.0)) < 0.05     # the plane at 3 m, seen
