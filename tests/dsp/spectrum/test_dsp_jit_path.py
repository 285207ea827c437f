"""A job's DSP path (lidard.dsp.spectrum.jit.plan_path / follow): decided once from its planned cells and
what is already paid for, followed by every DSP call of the thread that runs the job, and never seen by
another thread or by the same thread after the job."""

from __future__ import annotations

import importlib.util
import threading

import pytest

from lidard.dsp.spectrum import jit
from tests.helpers.jit_ab import as_a_fresh_process

needs_numba = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed")


@needs_numba
def test_the_break_even_counts_the_process_jobs_and_a_compiled_decision_loads_the_kernels(monkeypatch):
    as_a_fresh_process(monkeypatch)
    monkeypatch.setattr(jit, "LOAD_AFTER_CELLS", 1000)
    assert jit.plan_path(600) == "numpy"
    assert jit._compiled.cache_info().currsize == 0          # below the break-even: nothing loaded
    assert jit.plan_path(600) == "compiled"                   # 1,200 cells in this process's jobs
    assert jit._compiled.cache_info().currsize == 1          # loaded at the decision, before a batch
    assert jit.plan_path(0) == "compiled"                     # loaded: no cost left to weigh


@needs_numba
def test_a_job_on_the_pool_workers_is_compiled_without_loading_here(monkeypatch):
    as_a_fresh_process(monkeypatch)
    assert jit.plan_path(10, preloaded=True) == "compiled"
    assert jit._compiled.cache_info().currsize == 0 and jit._asked[0] == 0


def test_without_the_kernels_every_job_is_numpy(monkeypatch):
    monkeypatch.setenv("LIDARD_DSP_JIT", "0")
    assert not jit.installed()
    assert jit.plan_path(10 * jit.LOAD_AFTER_CELLS) == jit.plan_path(1, preloaded=True) == "numpy"
    with jit.follow("compiled"):
        assert jit.kernels() is None


def test_bad_paths_and_counts_are_named():
    with pytest.raises(ValueError, match="'fast' is not one of numpy, compiled"):
        with jit.follow("fast"):      # type: ignore[arg-type]
            pass
    with pytest.raises(ValueError, match="cells must be >= 0"):
        jit.plan_path(-1)


@needs_numba
def test_follow_is_the_thread_s_own_and_is_put_back_after(monkeypatch):
    as_a_fresh_process(monkeypatch)
    jit.kernels()                                      # loaded in this process
    inside, other = threading.Event(), {}

    def another_job():
        inside.wait(10)
        other["kernels"] = jit.kernels(1)               # no job on this thread: the process's kernels
        with jit.follow("numpy"):
            other["numpy"] = jit.kernels(1)

    t = threading.Thread(target=another_job)
    t.start()
    with jit.follow("numpy"):
        assert jit.kernels(1) is None
        with jit.follow("compiled"):
            assert jit.kernels(1) is not None
        assert jit.kernels(1) is None                  # the outer job's path again
        inside.set()
        t.join(10)
    assert other == {"kernels": jit._compiled(), "numpy": None}
    assert jit.kernels(1) is not None                  # after the job: the process's rule
