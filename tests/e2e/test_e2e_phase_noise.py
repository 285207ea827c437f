"""End to end: laser phase-noise compensation in a real scan on the embedded simulated bench (§2.3).

The broad-linewidth DFB preset (tau_c = 0.1 us) and a wall at 89.94 m (round trip 600 ns = 3 x the
200 ns monitor delay, so 2 tau / tau_c = 12: eq. 2-14 puts the plain peak ~100 dB down, into the
phase-noise pedestal). The shipped link (1 mW out through the FPSA's losses) leaves a 90 m wall at
~5 dB post-FFT SNR even with an ideal laser, below any useful detection threshold, so the bench's
transmitter is raised to 100 mW (LIDARD__LINK__TX_POWER_W): the test then measures the phase noise,
not the link budget. The digitizer records the monitor MZI in the same segments as the beat.
"""

import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import open_instrument
from lidard.instrument import ScanRequest
from tests.helpers.ilc_budget import capped_ilc_averages
from tests.helpers.tolerances import NOMINAL_ENV

pytestmark = pytest.mark.slow  # a broad-linewidth bench linearized, far-wall scans (~10 s CPU)

C = 299_792_458.0
WALL_Z_M = 3 * 200e-9 * C / 2          # 89.94 m: round trip 3 tau_m


@pytest.fixture(scope="module")
def far_wall():
    cfg = load_config("config/sim.toml", environ={**NOMINAL_ENV, "LIDARD__LASER": "dfb_broad_linewidth",
                                                  "LIDARD__LINK__TX_POWER_W": "0.1"})
    assert cfg.monitor.delay_s == pytest.approx(200e-9)
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    inst.set_scene({"target": [{"kind": "plane", "point": [0.0, 0.0, WALL_Z_M], "normal": [0.0, 0.0, -1.0],
                                "size": [60.0, 60.0], "up": [0.0, 1.0, 0.0], "reflectivity": 0.9}]})
    # the averages stop doubling at 256 (not 2048): ~6 s of CPU instead of ~26 s. Both scans of a test
    # use this one chirp, so "ranged with compensation, missed without" still isolates the compensation
    with capped_ilc_averages(256):
        cal = inst.linearize()
    yield inst, bench, cal
    inst.close()


def _scan(inst, cal, mode, max_range_m=110.0):
    req = ScanRequest(pattern="roi", rows=(60, 64), cols=(60, 64), averages=2, max_range_m=max_range_m,
                      phase_noise_compensation=mode)
    res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
    assert res.pixels_scanned == res.pixels_planned and not res.partial
    return res


def _ranged(res, bench):
    """Pixels with a valid point within one range resolution cell of the ray-cast truth."""
    pts = res.points
    truth = bench.ground_truth(pts["row"], pts["col"])
    assert np.all(np.abs(truth - WALL_Z_M) < 0.5)       # every beam of the ROI hits the wall
    cell = res.meta["dsp"]["range_resolution_m"]
    good = (pts["valid"] == 1) & (np.abs(pts["range"] - truth) <= cell)
    return {(int(r), int(c)) for r, c in zip(pts["row"][good], pts["col"][good])}


def test_far_wall_is_ranged_with_compensation_and_missed_without(far_wall):
    inst, bench, cal = far_wall
    on = _scan(inst, cal, "auto")           # 110 m: round trip 733 ns >= 2 tau_m, so auto is on
    off = _scan(inst, cal, "off")
    assert on.meta["dsp"]["phase_noise_compensation"] is True
    assert off.meta["dsp"]["phase_noise_compensation"] is False
    pn = on.meta["dsp"]["phase_noise"]
    assert pn["mzi_delay_s"] == pytest.approx(200e-9)
    # bins of a 0.05..110 m gate (+ Doppler) take their nearest M: 0 near, round(733 / 200) = 4 far
    assert pn["m_range"] == [0, 4]
    n = on.pixels_planned
    hit_on, hit_off = _ranged(on, bench), _ranged(off, bench)
    assert len(hit_on) >= 0.9 * n, (len(hit_on), n)
    assert len(hit_off) < len(hit_on)
    assert len(hit_off) <= 0.25 * n


def test_auto_stays_off_for_short_ranges(far_wall):
    inst, _, cal = far_wall
    res = _scan(inst, cal, None, max_range_m=20.0)     # config default "auto": 133 ns < 2 tau_m
    assert res.meta["dsp"]["phase_noise_compensation"] is False
    assert "phase_noise" not in res.meta["dsp"]
