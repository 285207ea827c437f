"""What a linearization reports about its own residual chirp error: per ILC measurement the RMS
nonlinearity and RMS error of each ramp, the periods averaged and the noise floor; which measurement's
drive was kept and the bandwidth it was learned in. The range-linearity test
(tests/e2e/test_e2e_range_linearity.py) turns the kept drive's error into the range error a plate may
carry. No linearization is run: the ILC is replaced by a stub that answers a known result."""

from __future__ import annotations

import json
import math

import numpy as np

from lidard.config import CONFIG_DIR, load_config
from lidard.dsp.linearize.ilc import IlcIteration, IlcResult
from lidard.instrument.acquisition import AWG_RATE_HZ
from lidard.instrument.calibration import linearization as lin_mod


class _Safety:
    def bring_up(self):
        pass

    def bring_down(self):
        pass


def _it(k: int, err: tuple[float, float], nl: tuple[float, float], noise: float, averages: int) -> IlcIteration:
    return IlcIteration(index=k, up_rms_hz=nl[0], down_rms_hz=nl[1], up_error_hz=err[0], down_error_hz=err[1],
                        noise_floor_hz=noise, tuning_hz_per_v=1e9, beta=0.8, phase_slips=0, accepted=True,
                        averages=averages)


def _run_with(monkeypatch, result: IlcResult):
    cfg = load_config(CONFIG_DIR / "sim_far.toml")          # triangle chirp: no held segment to measure
    monkeypatch.setattr(lin_mod, "ilc_linearize", lambda measure, drive_v, geometry, settings: result)
    lin = lin_mod.Linearization(cfg, cfg.resolved.optics, lifecycle=None, safety=_Safety())  # type: ignore[arg-type]
    return lin.run(np.zeros(int(round(2 * cfg.chirp.ramp_s * AWG_RATE_HZ))), cfg.laser)


def test_reports_each_measurements_error_noise_floor_and_the_drive_kept(monkeypatch):
    its = [_it(0, (4.3e8, 4.4e8), (7.6e7, 8.8e7), math.nan, 1),      # one period: no noise floor
           _it(1, (4.2e4, 3.5e4), (4.1e4, 3.5e4), 17.0, 32),
           _it(2, (4.5e4, 3.8e4), (4.4e4, 3.7e4), 18.0, 64)]
    res = IlcResult(drive_v=np.zeros(int(round(2 * 80e-6 * AWG_RATE_HZ))), iterations=its,  # sim_far: 80 us ramps
                    reduction={"up": 1800.0, "down": 2500.0}, converged=True,
                    tuning_hz_per_v=1e9, best_iteration=1, phase_slips=0, stop_reason="error stopped improving",
                    meta={"q_cutoff_hz": 1.0e6})
    cal = _run_with(monkeypatch, res)
    assert [it["up_error_hz"] for it in cal.iterations] == [4.3e8, 4.2e4, 4.5e4]
    assert [it["down_error_hz"] for it in cal.iterations] == [4.4e8, 3.5e4, 3.8e4]
    assert [it["up_rms_hz"] for it in cal.iterations] == [7.6e7, 4.1e4, 4.4e4]
    assert [it["averages"] for it in cal.iterations] == [1.0, 32.0, 64.0]
    assert "noise_floor_hz" not in cal.iterations[0]                   # not measurable: left out, not NaN
    assert [it["noise_floor_hz"] for it in cal.iterations[1:]] == [17.0, 18.0]
    kept = cal.iterations[cal.meta["best_iteration"]]
    assert kept["up_error_hz"] == 4.2e4 and kept["down_error_hz"] == 3.5e4
    assert cal.meta["learning_bandwidth_hz"] == 1.0e6
    # the record is finite JSON (the API and the store write it)
    json.dumps({"iterations": cal.iterations, "meta": {k: v for k, v in cal.meta.items()}}, allow_nan=False)
