"""The Doppler band is a scan request (scan.max_speed_mps, ``max_speed_mps`` of a scan): it sizes the
digitizer, and a target faster than the band is never placed at a wrong range.

Truth: the bench's ray-cast range of each pixel, moved to each point's own time, and the radial
velocity d . v (positive receding). At config/sim.toml's static-scene band (0.4 m/s: 5 MHz records)
a target inside the band is ranged and its speed measured; one faster than the band gives no point
(its beat lies beyond the record's band, which the digitizer's decimation filter removes) or, where
both ramp beats and the CW beat still fit the record, a correct one; never a point at a wrong range.
The same targets asked for with a 10 m/s band are all ranged.
"""

import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from sim_devices.world.scene import Scene
from tests.helpers.tolerances import NOMINAL_ENV

pytestmark = pytest.mark.slow

ROI = {"pattern": "roi", "rows": (60, 62), "cols": (62, 66), "max_range_m": 2.0}


def _plane(z_m, v_mps):
    return {"kind": "plane", "point": [0.0, 0.0, z_m], "normal": [0.0, 0.0, -1.0], "size": [4 * z_m, 4 * z_m],
            "up": [0.0, 1.0, 0.0], "reflectivity": 0.3, "velocity": [0.0, 0.0, v_mps]}


@pytest.fixture(scope="module")
def rig():
    cfg = load_config("config/sim.toml", environ=NOMINAL_ENV)
    inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    try:
        yield cfg, inst, inst._on_close.__self__, inst.linearize()
    finally:
        inst.close()


def _scan(rig, z_m, v_mps, **kw):
    cfg, inst, bench, cal = rig
    bench.set_scene(Scene.from_dict({"name": "one", "target": [_plane(z_m, v_mps)]}))
    res = inst.run_scan(ScanRequest(**ROI, **kw), lambda p: None, threading.Event(), cal)
    pts = res.points
    v_true = inst.optics.directions(pts["row"], pts["col"]) @ np.array([0.0, 0.0, v_mps])
    r_true = bench.ground_truth(pts["row"], pts["col"]) + v_true * pts["t"]
    return res, pts, pts["range"] - r_true, pts["velocity"] - v_true


def test_the_default_band_is_the_static_scenes_and_the_sidecar_records_it(rig):
    cfg = rig[0]
    res, pts, dr, dv = _scan(rig, 1.0, -0.3)
    band = res.meta["adc"]["max_speed_mps"]
    assert band == cfg.scan.max_speed_mps == 0.4
    assert res.meta["adc"]["doppler_band_hz"] == pytest.approx(2 * band / cfg.chirp.wavelength_m)
    # the rate holds the 2 m range beat plus the band's Doppler at 2.5x Nyquist, not a 10 m/s band
    f_need = 2.5 * (2 * cfg.chirp.rate_hz_per_s * 2.0 / 299_792_458.0 + 2 * band / cfg.chirp.wavelength_m)
    assert f_need <= res.meta["adc"]["sample_rate_hz"] < 2.5 * 2 * 10.0 / cfg.chirp.wavelength_m
    # inside the band: every pixel ranged, the speed measured
    assert len(pts) == res.pixels_scanned and pts["valid"].all()
    assert np.sqrt(np.mean(dr ** 2)) <= 1e-3 and np.max(np.abs(dv)) <= 0.05


@pytest.mark.parametrize("z_m", [0.5, 1.9])
@pytest.mark.parametrize("v_mps", [0.6, -0.8, 1.5, -3.0, 6.0, -12.0])
def test_a_target_faster_than_the_band_is_never_ranged_wrong(rig, z_m, v_mps):
    res, pts, dr, dv = _scan(rig, z_m, v_mps)
    assert res.meta["adc"]["max_speed_mps"] == 0.4 < abs(v_mps)
    ok = pts["valid"] == 1
    # a valid point is the target's, at its range and speed; no point elsewhere in the gate
    assert np.all(np.abs(dr[ok]) <= 3e-3) and np.all(np.abs(dv[ok]) <= 0.05)
    assert np.all(np.abs(dr[~ok]) <= 0.05), "a flagged point drawn far from the target"


@pytest.mark.parametrize("z_m, v_mps", [(0.5, 6.0), (1.9, -0.8), (1.0, -3.0)])
def test_the_same_targets_asked_with_a_wider_band_are_ranged(rig, z_m, v_mps):
    res, pts, dr, dv = _scan(rig, z_m, v_mps, max_speed_mps=10.0)
    assert res.meta["adc"]["max_speed_mps"] == 10.0
    assert len(pts) == res.pixels_scanned and pts["valid"].all()
    assert np.sqrt(np.mean(dr ** 2)) <= 1e-3 and np.max(np.abs(dv)) <= 0.05


@pytest.mark.parametrize("v_mps", [1.2, -1.2])
def test_a_target_at_three_times_the_band_is_flagged_out_of_band_where_it_is_drawn(rig, v_mps):
    # 0.12 m: both ramp beats (f_R + 3 x the band's Doppler) still lie inside the searched band, so the
    # target is measured, and drawn at its range; its speed is 3x what the record was sized for: flagged
    from lidard.dsp.detect.gate import PointFlag
    res, pts, dr, dv = _scan(rig, 0.12, v_mps)
    assert res.meta["adc"]["max_speed_mps"] == 0.4
    assert not pts["valid"].any()
    assert len(pts) > 0
    assert np.all(pts["flags"] & PointFlag.OUT_OF_BAND)
    assert np.all(np.abs(dr) <= 3e-3) and np.all(np.abs(dv) <= 0.05)
