"""Motion on the default configuration (issue 14 item 1, half of item 5): the three-segment chirp ranges
approaching and receding targets, folded and not, from 0.3 m to the gate, with no speed prior.

Truth: the bench's ray-cast range of each pixel and the radial velocity direction . v (positive
receding); ``_truth_range`` moves a target to each point's own hardware time ``t`` (the bench moves
targets during a scan, issue 14 item 3).
"""

import dataclasses
import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from sim_devices.world.scene import Scene
from tests.helpers.tolerances import NOMINAL_ENV
from tests.helpers.tone_test import assert_every_pixel_ranged

pytestmark = pytest.mark.slow  # moving-target benches, linearized

WL = 1.55e-6
KAPPA = 8.6e9 / 80e-6
C = 299_792_458.0


def _regime_boundary_speed(range_m):
    return WL * (2 * KAPPA * range_m / C) / 2          # |f_D| = f_R


def _plane(z_m, v_mps, x_m=0.0, y_m=0.0, size_m=None):
    return {"kind": "plane", "point": [x_m, y_m, z_m], "normal": [0.0, 0.0, -1.0],
            "size": [size_m or 4 * z_m, size_m or 4 * z_m], "up": [0.0, 1.0, 0.0], "reflectivity": 0.3,
            "velocity": [0.0, 0.0, v_mps]}


@pytest.fixture(scope="module")
def motion():
    cfg = load_config("config/sim.toml")
    assert cfg.chirp.shape == "three_segment"           # the default: no speed prior
    inst = open_instrument(cfg, scene_path="config/scenes/cal_letters.toml", bench="embedded")
    bench = inst._on_close.__self__
    cal = inst.linearize()
    yield inst, bench, cal
    inst.close()


def _truth(inst, bench, pts, v_mps):
    d = inst.optics.directions(pts["row"], pts["col"])
    v_r = d @ np.array([0.0, 0.0, v_mps])
    r = bench.ground_truth(pts["row"], pts["col"])
    return r + v_r * pts["t"], v_r


def _scan(inst, cal, req):
    return inst.run_scan(req, lambda p: None, threading.Event(), cal)


# (range, speed): not folded, folded (|f_D| > f_R), approaching and receding, 0.3 m to the 2 m gate;
# and where the regimes meet (|f_D| = f_R: one ramp beat at DC), on both sides of it
CASES = [(0.3, 0.0), (0.3, 4.7), (0.3, -5.0), (0.7, 0.12), (0.7, -2.2), (1.3, 0.45), (1.3, -0.6), (1.3, 5.0),
         (1.9, -0.8), (1.9, 3.3), (1.95, -5.0),
         (0.6, _regime_boundary_speed(0.6)), (1.0, -_regime_boundary_speed(1.0)),
         (1.5, 0.97 * _regime_boundary_speed(1.5)), (1.9, -1.03 * _regime_boundary_speed(1.9))]


@pytest.mark.parametrize("range_m, v_mps", CASES)
def test_region_scan_ranges_moving_targets_with_signed_velocity(motion, range_m, v_mps):
    inst, bench, cal = motion
    bench.set_scene(Scene.from_dict({"name": "one", "target": [_plane(range_m, v_mps)]}))
    res = _scan(inst, cal, ScanRequest(pattern="roi", rows=(60, 64), cols=(62, 66), max_range_m=2.0, max_speed_mps=10.0))
    # every pixel ranged, one point each (but for the single-tone test's own rare false rejections,
    # drawn and flagged: tests/helpers/tone_test.py)
    pts = assert_every_pixel_ranged(res)
    r_true, v_true = _truth(inst, bench, pts, v_mps)
    assert np.all(np.abs(pts["velocity"] - v_true) <= 0.05)
    assert np.sqrt(np.mean((pts["range"] - r_true) ** 2)) <= 1e-3
    if v_mps:
        assert np.all(np.sign(pts["velocity"]) == np.sign(v_mps))


def test_linearization_measures_the_held_segments_drift(motion):
    # the DFB's thermal terms drift through the hold by hundreds of MHz (the bench's laser model,
    # measured independently here from its periodic steady state under the learned drive)
    from lidard.instrument.acquisition import AWG_RATE_HZ
    from lidard.dsp.ranging.cwhold import HoldProfile
    inst, bench, cal = motion
    prof = HoldProfile.from_dict(cal.meta["hold_profile"])
    nu = bench.laser.frequency_hz(cal.drive_v, AWG_RATE_HZ)
    t = prof.t0_s + prof.dt_s * np.arange(len(prof.nu_hz))
    truth = np.interp(t, np.arange(nu.size) / AWG_RATE_HZ, nu)
    truth -= truth[0]
    assert np.ptp(truth) > 100e6                          # a drift the CW beat cannot ignore
    # signed: the real fringe's drift is taken to continue the down ramp (lidard.dsp.ranging.cwhold), and the
    # bench's laser (its up ramp raises nu) drifts that way
    nu_up = bench.laser.frequency_hz(cal.drive_v, AWG_RATE_HZ)[:int(80e-6 * AWG_RATE_HZ)]
    assert nu_up[-1] > nu_up[0]
    err = np.asarray(prof.nu_hz) - truth
    assert np.max(np.abs(err[len(err) // 10:])) < 0.005 * np.ptp(truth)


def test_regime_boundary_without_a_hold_profile_is_flagged_not_misranged(motion):
    # a linearization stored before the drift was measured: |f_D| = f_R cannot be resolved (both
    # regimes explain the spread CW beat); the pixel is drawn, not valid, and never misranged
    inst, bench, cal = motion
    old = dataclasses.replace(cal, meta={k: v for k, v in cal.meta.items() if k != "hold_profile"})
    v = -_regime_boundary_speed(1.0)
    bench.set_scene(Scene.from_dict({"name": "edge", "target": [_plane(1.0, v)]}))
    res = _scan(inst, old, ScanRequest(pattern="roi", rows=(60, 62), cols=(62, 64), max_range_m=2.0, max_speed_mps=10.0))
    assert not np.any(res.points["valid"] == 1)
    assert res.meta["dsp"]["hold_profile"] is False          # the sidecar says why
    with_profile = _scan(inst, cal, ScanRequest(pattern="roi", rows=(60, 62), cols=(62, 64), max_range_m=2.0, max_speed_mps=10.0))
    assert np.count_nonzero(with_profile.points["valid"] == 1) == with_profile.pixels_scanned
    assert with_profile.meta["dsp"]["hold_profile"] is True


@pytest.fixture(scope="module")
def small_frame():
    # the 20 x 20 FPSA of §4.2 (f = 4.51 mm, 32 deg FoV): a full frame of 400 pixels takes 0.1 s of
    # hardware time, so targets at several m/s stay in their regime while it is scanned (a 128 x 96
    # frame takes 3 s: a 5 m/s target moves 15 m, out of the gate or through the sensor)
    cfg = load_config("config/sim.toml", environ={**NOMINAL_ENV, "LIDARD__PROFILE": "fpsa20",
                                                  "LIDARD__LENS": "singlet_4p51mm"})
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    yield inst, inst._on_close.__self__, inst.linearize()
    inst.close()


def test_full_frame_of_moving_targets_near_and_far(small_frame):
    # four patches, one per quadrant: 0.3 m receding fast (folded), 0.8 m receding slowly, 1.4 m
    # approaching where the regimes meet (|f_D| = f_R at its start, 6 % past it by the frame's end),
    # 1.9 m approaching fast (folded); the rest of the frame sees nothing. The scene moves during the
    # frame: the truth of each point is at its own t.
    inst, bench, cal = small_frame
    patches = [(0.3, 2.0, -0.15, -0.15), (0.8, 0.2, 0.15, -0.15), (1.4, -_regime_boundary_speed(1.4), -0.15, 0.15),
               (1.9, -3.0, 0.15, 0.15)]
    bench.set_scene(Scene.from_dict({"name": "patches", "target": [
        _plane(z, v, x * z, y * z, size_m=0.24 * z) for z, v, x, y in patches]}))
    res = _scan(inst, cal, ScanRequest(pattern="raster", max_range_m=2.0, max_speed_mps=10.0))
    assert res.pixels_scanned == res.pixels_planned == 400
    assert res.hardware_time_s < 0.12
    pts = res.points[res.points["valid"] == 1]
    # analytic truth: a plane z = z_k + v_k t facing the sensor is at range (z_k + v_k t) / d_z along
    # the beam d, its radial velocity v_k d_z; each point is held to the patch whose range is nearest
    d_z = inst.optics.directions(pts["row"], pts["col"])[:, 2]
    t = pts["t"]
    r_k = np.stack([(z + v * t) / d_z for z, v, _, _ in patches])
    k = np.argmin(np.abs(r_k - pts["range"]), axis=0)
    r_true = r_k[k, np.arange(len(pts))]
    v_true = np.array([v for _, v, _, _ in patches])[k] * d_z
    assert np.all(np.abs(pts["range"] - r_true) <= 0.01)   # no valid point at a range no patch has
    for i, (z, v, _, _) in enumerate(patches):
        on = k == i
        assert on.sum() >= 20, (z, v, on.sum())
        bad = np.abs(pts["velocity"][on] - v_true[on]) > 0.05
        assert not bad.any(), (z, v, pts[on][bad])
        assert np.sign(pts["velocity"][on]).tolist() == [np.sign(v)] * int(on.sum())
        assert np.sqrt(np.mean((pts["range"][on] - r_true[on]) ** 2)) <= 1e-3, (z, v)


def test_averaged_points_refer_to_their_first_trigger(motion):
    # three averages span 0.7 ms of hardware time, in which a target at 5 m/s moves 3.6 mm: the DSP's
    # range refers to the mean of the triggers' ramp centres (FrameDsp.measurement_delay_s, 318 us
    # after the first trigger), and each point is moved back to its own t with its velocity
    inst, bench, cal = motion
    v = -5.0
    bench.set_scene(Scene.from_dict({"name": "fast", "target": [_plane(1.5, v)]}))
    res = _scan(inst, cal, ScanRequest(pattern="roi", rows=(60, 62), cols=(62, 66), max_range_m=2.0, max_speed_mps=10.0, averages=3))
    pts = assert_every_pixel_ranged(res)
    r_true, v_true = _truth(inst, bench, pts, v)
    delay = 80e-6 + 0.5 * 2 * 238e-6               # ramp_s + (averages - 1) / 2 periods (config/sim.toml)
    assert np.sqrt(np.mean((pts["range"] - r_true) ** 2)) <= 1e-3
    # without the move the points would sit v x delay = 1.6 mm off: the correction is what is measured
    assert np.all(np.abs(pts["range"] - r_true) < 0.2 * abs(v) * delay)


def test_a_target_smeared_over_many_averages_is_flagged_not_misranged(motion):
    # ten averages (2.4 ms) at 5 m/s: 12 mm of motion, 0.7 range bins, smear the averaged spectrum's
    # peak; the shape test reads it as unresolved: drawn with its flag, never a valid wrong range
    inst, bench, cal = motion
    bench.set_scene(Scene.from_dict({"name": "fast", "target": [_plane(1.5, -5.0)]}))
    res = _scan(inst, cal, ScanRequest(pattern="roi", rows=(60, 62), cols=(62, 66), max_range_m=2.0, max_speed_mps=10.0, averages=10))
    pts = res.points
    r_true, _ = _truth(inst, bench, pts, -5.0)
    ok = pts["valid"] == 1
    assert np.all(np.abs(pts["range"][ok] - r_true[ok]) <= 2e-3)
    assert np.all(pts["flags"][~ok] & 1)                 # PointFlag.UNRESOLVED
