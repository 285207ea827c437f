"""End to end (issue 14, item 3): targets move during a scan. A box moving at 1.5 m/s (laterally and
radially) in front of a wall, scanned over a 32 x 32 pixel frame (~0.17 s of hardware time: the box
moves ~0.25 m meanwhile): every point is compared with the ray-cast truth of the scene moved to that
point's own ``t`` (range and x/y/z), and a static scene keeps the per-pixel cast cache (counted casts)."""

import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from tests.helpers.tolerances import NOMINAL_ENV

pytestmark = pytest.mark.slow  # moving-scene benches, linearized

V_MPS = (1.0, 0.0, 1.1)          # |v| = 1.49 m/s: across the beams and along them
FRAME = dict(pattern="roi", rows=(48, 80), cols=(48, 80))


def scene(v=V_MPS) -> dict:
    return {"target": [
        {"kind": "box", "center": [-0.25, 0.0, 4.3], "size": [0.5, 0.5, 0.1], "reflectivity": 0.8,
         "velocity": list(v)},
        {"kind": "plane", "point": [0.0, 0.0, 6.0], "normal": [0.0, 0.0, -1.0], "reflectivity": 0.9}]}


@pytest.fixture(scope="module")
def embedded():
    # a real beat needs a speed prior above 1.5 m/s; ranges beyond ~3.6 m are then unambiguous. The
    # triangle's greedy up/down pairing takes a CFAR false alarm near the box's up beat for its down
    # beat (a point metres off, ~1 per 10^6 cells at a per-ramp level of 1e-6): a per-ramp level of 1e-9
    # keeps this test about motion. scan.pfa is false points per range cell, the per-ramp level
    # sqrt(pfa / m) with m ~ 10 on this chirp (lidard.dsp.ranging.points): 1e-17. (Such a pair, a true
    # peak with a noise peak, is not in that rate: it counts pairs of noise peaks only.)
    cfg = load_config("config/sim.toml", environ={**NOMINAL_ENV, "LIDARD__SCAN__MAX_SPEED_MPS": "2.0",
                                                  "LIDARD__SCAN__PFA": "1e-17"})
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    cal = inst.linearize()
    yield inst, bench, cal
    inst.close()


def _scan(inst, cal, scn):
    inst.set_scene(scn)
    return inst.run_scan(ScanRequest(max_range_m=7.0, max_speed_mps=10.0, **FRAME), lambda p: None, threading.Event(), cal)


def test_points_follow_the_target_to_their_own_time(embedded):
    inst, bench, cal = embedded
    res = _scan(inst, cal, scene())
    pts = res.points[res.points["valid"] == 1]
    assert res.hardware_time_s > 0.1
    truth_t = bench.ground_truth(pts["row"], pts["col"], pts["t"])
    on_box = truth_t < 5.0
    assert on_box.sum() >= 60                      # the box is seen on many pixels ...
    assert np.ptp(pts["t"][on_box]) > 0.1          # ... over most of the frame's time
    err = pts["range"] - truth_t
    assert np.sqrt(np.mean(err[on_box] ** 2)) <= 1e-3
    assert np.sqrt(np.mean(err[~on_box] ** 2)) <= 1e-3
    # x/y/z: along each beam, at the moved truth
    d = bench.world.optics.directions(pts["row"], pts["col"])
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float64)
    assert np.max(np.linalg.norm(xyz - d * truth_t[:, None], axis=1)[on_box]) < 5e-3
    # radial velocity v . d on the box
    assert np.max(np.abs(pts["velocity"][on_box] - d[on_box] @ np.array(V_MPS))) <= 0.05
    # the frozen scene (t = 0) is not what was measured: late points are centimetres off it
    frozen = bench.ground_truth(pts["row"], pts["col"])
    late = on_box & (pts["t"] > 0.1) & (frozen < 5.0)
    assert late.sum() >= 10 and np.min(np.abs(pts["range"][late] - frozen[late])) > 0.05
    # no point on the box where the moved truth has none (its edges at each pixel's time)
    assert not np.any((~on_box) & (pts["range"] < 5.5))


def test_static_scene_keeps_the_per_pixel_cast_cache(embedded):
    inst, bench, cal = embedded
    w = bench.world
    n0, m0 = w.rays_cast, w.moving_rays_cast
    res = _scan(inst, cal, scene(v=(0.0, 0.0, 0.0)))
    assert w.rays_cast - n0 == res.pixels_planned          # one cast per pixel, as before motion
    assert w.moving_rays_cast == m0                          # nothing cast per beam
    n1 = w.rays_cast
    inst.run_scan(ScanRequest(max_range_m=7.0, max_speed_mps=10.0, **FRAME), lambda p: None, threading.Event(), cal)
    assert w.rays_cast == n1                                 # the cache serves a second scan
    # a moving box: the static wall still once per pixel, the box once per lit beam (the FPGA's
    # record of the run: a beam per trigger, and the previous pixel's while its switch releases)
    res = _scan(inst, cal, scene())
    assert w.rays_cast - n1 == res.pixels_planned
    adc = res.meta["adc"]
    lit = bench.fpga.triggers(0, bench.fpga.total_triggers, adc["record_length"] / adc["sample_rate_hz"])
    beams = len(lit.beam_trigger) if bench.cfg.sim.effects.mems_dynamics else res.pixels_planned
    assert w.moving_rays_cast - m0 == beams >= res.pixels_planned
