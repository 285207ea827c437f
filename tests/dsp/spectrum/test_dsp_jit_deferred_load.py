"""numba is loaded only once the DSP has asked for LOAD_AFTER_CELLS spectrum cells (lidard.dsp.spectrum.jit):
a small job keeps the numpy path (the same values, tests/dsp/spectrum/test_dsp_jit.py) and never pays the load."""

import json
import subprocess
import sys

import pytest

_PROBE = """
import json, sys
import numpy as np
from lidard.dsp.spectrum import jit
from lidard.dsp.detect.cfar import CfarSettings, cfar_detect_with
p = np.random.default_rng(1).exponential(size=(64, 512))
p[:, 100] += 1e3
small = cfar_detect_with(p, CfarSettings(method="os", pfa=1e-6))          # 32 k cells: numpy
before = "numba" in sys.modules
k_small = jit.kernels(1000)
k_big = jit.kernels(jit.LOAD_AFTER_CELLS)               # the count passes the threshold: loaded
big = cfar_detect_with(p, CfarSettings(method="os", pfa=1e-6))
print(json.dumps({"before": before, "k_small": k_small is None, "k_big": k_big is not None,
                  "same": bool(np.array_equal(small.index, big.index) and np.array_equal(small.valid, big.valid)),
                  "found": bool(small.valid.any())}))
"""


def test_a_small_job_does_not_load_numba_and_a_large_one_does():
    try:
        import numba  # noqa: F401
    except ImportError:
        pytest.skip("numba is not installed")
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=300, check=True)
    rep = json.loads(out.stdout.strip().splitlines()[-1])
    assert rep == {"before": False, "k_small": True, "k_big": True, "same": True, "found": True}
