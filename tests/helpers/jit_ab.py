"""The frame DSP's compiled kernels against its numpy path, in one process."""

from __future__ import annotations

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
