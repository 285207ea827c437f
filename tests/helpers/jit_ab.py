"""The frame DSP's compiled kernels against its numpy path, in one process."""

from __future__ import annotations

from functools import lru_cache

from lidard.dsp.spectrum import jit


def compiled_and_numpy(monkeypatch, fn):
    """``fn()`` with the compiled kernels loaded, then with ``LIDARD_DSP_JIT=0`` (the numpy path):
    (compiled result, numpy result)."""
    jit.kernels()                       # loaded now, whatever the break-even rule would say
    got = fn()
    monkeypatch.setenv("LIDARD_DSP_JIT", "0")
    assert jit.kernels() is None
    want = fn()
    monkeypatch.delenv("LIDARD_DSP_JIT")
    return got, want


def as_a_fresh_process(monkeypatch) -> None:
    """This process's DSP kernels as a fresh process has them until the test ends: not loaded, no cells
    counted (a fresh cache of the loader in place of the process's; the process's own is put back after)."""
    monkeypatch.setattr(jit, "_compiled", lru_cache(maxsize=1)(jit._compiled.__wrapped__))
    monkeypatch.setattr(jit, "_asked", [0])
