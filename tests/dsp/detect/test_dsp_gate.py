"""The honest range gate (lidard.dsp.detect.gate): the gate ends at the top of the decimation filter's
alias-free band (fs - 0.6 fs = 0.4 fs), and a detection no stronger than a fold can be is ALIASED."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.dsp.frame import FrameDsp
from lidard.dsp.detect.gate import ALIAS_MARGIN, PointFlag, aliased, decimation_gate, gate_top_hz, point_flags

GAMMA = 8.6e9 / 80e-6


def test_gate_ends_at_the_alias_free_band():
    assert gate_top_hz(3e6, None) == 3e6
    assert gate_top_hz(3e6, 2e6) == 2e6 and gate_top_hz(1e6, 2e6) == 1e6
    g = decimation_gate(5e6, 1e9, 80.0, 1.0)
    assert g["alias_free_hz"] == pytest.approx(2e6)
    assert g["alias_ceiling_v"] == pytest.approx(0.5 * 1e-4)
    assert decimation_gate(1e9, 1e9, 80.0, 1.0) == {"alias_free_hz": None, "alias_ceiling_v": 0.0}


def test_frame_dsp_search_stops_at_the_alias_free_band():
    kw = dict(ramp_samples=400, fs_hz=5e6, chirp_rate_hz_per_s=GAMMA, wavelength_m=1.55e-6, max_range_m=3.5,
              max_speed_mps=0.4)
    wide = FrameDsp(**kw)
    cut = FrameDsp(**kw, **decimation_gate(5e6, 1e9, 80.0, 1.0))
    df = cut.rfft.delta_f
    assert wide.bin_range[1] * df > 2.4e6                      # 3.5 m + Doppler: to Nyquist, past 0.4 fs
    assert cut.bin_range[1] * df <= 2e6 + 3 * df               # cut at 0.4 fs (+ the 2-bin margin)


def test_aliased_and_flags():
    ceiling = 1e-4
    assert list(aliased(np.array([0.5e-4, ALIAS_MARGIN * ceiling, 2.1 * ceiling]), ceiling)) == [True, True, False]
    assert not aliased(np.array([1e-9]), 0.0).any()
    f = point_flags(unresolved=np.array([True, False, False]), leak=np.array([False, True, False]),
                    harmonic=np.array([False, False, False]), unpaired=np.array([True, False, False]))
    assert list(f) == [PointFlag.UNRESOLVED | PointFlag.AMBIGUOUS, PointFlag.ALIASED, 0]
    assert f.dtype == np.uint8
