"""The bench's quadrature monitor channel "mzi_q" (issue 15): with ``[monitor] quadrature`` the
digitizer serves the same MZI's 90-degree output on an input of its own; without it that input is
unconnected. Checked against the definition I = A cos(theta), Q = A sin(theta) of one fringe theta."""

import numpy as np

from sim_devices.digitizer.device import CaptureConfig
from tests.helpers.sim_bench import lit_bench

FS = 100e6
CAP = CaptureConfig(FS, 8000, ("beat", "mzi", "mzi_q"), 16, 1.0)


def _bench(quadrature: bool):
    return lit_bench({"LIDARD__MONITOR__QUADRATURE": str(quadrature).lower()}, [[60, 60], [61, 61]])


def test_quadrature_channel_is_the_same_fringe_90_degrees_on_with_its_own_noise():
    with _bench(True) as bench:
        cap = bench.capture(0, 4, CAP)
    lsb = CAP.input_range_v / 2 ** CAP.bits
    i = cap.codes[:, 1].astype(float) * lsb
    q = cap.codes[:, 2].astype(float) * lsb
    a = bench.cfg.monitor.amplitude_v
    # I^2 + Q^2 = A^2 for one fringe read in quadrature (the phase noise cancels in the modulus)
    mod = np.hypot(i - i.mean(axis=1, keepdims=True), q - q.mean(axis=1, keepdims=True))
    assert np.median(np.abs(mod - a)) < 0.05 * a
    # 90 degrees apart: Q is uncorrelated with I but follows I's derivative
    assert abs(np.corrcoef(i.ravel(), q.ravel())[0, 1]) < 0.1
    # its own input: the sample-to-sample noise of Q is not I's (noise of the two inputs independent)
    di, dq = np.diff(i, 2, axis=1).ravel(), np.diff(q, 2, axis=1).ravel()
    assert abs(np.corrcoef(di, dq)[0, 1]) < 0.5
    assert not cap.overrange.any()


def test_without_the_hybrid_the_quadrature_input_reads_nothing():
    with _bench(False) as bench:
        cap = bench.capture(0, 4, CAP)
    assert np.all(cap.codes[:, 2] == 0)
    assert np.ptp(cap.codes[:, 1].astype(int)) > 1000    # the in-phase MZI is there as before
