"""A sweep task and a scan of the same pixel on the simulated bench give the same points.

Both take their signal path from the one constructor (lidard.instrument.dsp_plan.plan_signal: ADC plan,
three-segment record, FrameDsp) and their beat from the same synthesis (sim_devices.world.synth with
the digitizer's decimation filter). The bench is set so that the scan's chirp is the sweep's
linearized one: the "ideal" laser (a linear FM response, no thermal terms) under the daemon's plain
drive, no tolerances (the nominal geometry is the truth), the commanded beam only (no MEMS dynamics),
and the sweep's noise drawn as the bench draws it (its white noise's stream and its read's generator;
a sweep task seeds its own otherwise). What remains different is the bench's AWG: its drive is played from int16 DAC
codes, so its chirp departs from the exact drive by the codes' rounding; the tolerances below are
that, measured, well under the noise's own scatter (the CRLB).
"""

from __future__ import annotations

import threading

import numpy as np
import pytest

from lidard.instrument import open_instrument
from lidard.instrument.types import CalibrationResult, ScanRequest
from lidard.offline.spec import expand_sweep
from lidard.offline.sweep import calibration, crlb_range_m, linear_trajectory, task_frame
from lidard.raw.points import frame_points
from sim_devices.world.gauss import NoiseStream, stream_key

GRID = {"laser": "ideal", "scan.max_range_m": 4.0, "sim.effects.mems_dynamics": False}


def _bench_rng(task) -> np.random.Generator:
    """The noise generator of the bench's first read of its first run (SegmentSynthesizer._synthesize)."""
    return np.random.default_rng([task.point.cfg.sim.seed, 1, 0])


def _bench_noise(task) -> NoiseStream:
    """The white noise's stream of the bench's first run from its first trigger (the bench keys it by
    seed and run; a record's noise is a function of its trigger index, whatever the reads)."""
    return NoiseStream(stream_key(task.point.cfg.sim.seed, 1), 0)


def _task(distance_m: float, velocity_mps: float, shape: str = "three_segment"):
    raw = {"sweep": {"seeds": 1, "trials_per_task": 1}, "grid": {**GRID, "chirp.shape": shape},
           "target": {"distances_m": [distance_m], "reflectivity": 0.5, "velocity_mps": velocity_mps}}
    (task,) = expand_sweep(raw).tasks
    return task


def _scene_toml(task, row: int, col: int) -> str:
    """The sweep task's target (lidard.offline.sweep._world) as a scene file."""
    pt = task.point
    u = pt.profile.optics(pt.cfg.lens, pt.cfg.chirp.wavelength_m).directions(np.array([row]), np.array([col]))[0]
    def vec(a: np.ndarray) -> str:
        return "[" + ", ".join(repr(float(x)) for x in a) + "]"
    return (f'[[target]]\nkind = "plane"\npoint = {vec(u * task.distance_m)}\nnormal = {vec(-u)}\n'
            f"reflectivity = {task.reflectivity!r}\nvelocity = {vec(u * task.velocity_mps)}\n")


def _scan_points(task, tf, tmp_path):
    """The points of a scan of the task's pixel on a bench whose scene is the task's target."""
    cfg = task.point.cfg
    tol = cfg.sim.tolerances.model_copy(update={"enabled": False})
    cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"tolerances": tol})})
    scene = tmp_path / "target.toml"
    row, col = tf.pixel
    scene.write_text(_scene_toml(task, row, col))
    # the DSP's calibration as the sweep gives it (the held segment's drift of the linearized chirp)
    hold = calibration(cfg, linear_trajectory(cfg), tf.plan.adc).hold_profile
    cal = CalibrationResult(iterations=[], reduction={}, converged=True, laser="ideal", temperature_c=25.0,
                            meta={"hold_profile": hold})
    inst = open_instrument(cfg, scene_path=str(scene), bench="embedded")
    try:
        req = ScanRequest(pattern="pixels", pixels=((row, col),), averages=cfg.scan.averages,
                          max_range_m=cfg.scan.max_range_m)
        res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
    finally:
        inst.close()
    return res.points, res.meta


def test_a_sweep_runs_the_scans_default_chirp():
    raw = {"sweep": {"seeds": 1, "trials_per_task": 1}, "target": {"distances_m": [2.0]}}
    (task,) = expand_sweep(raw).tasks
    plan = task_frame(task).plan
    assert task.point.cfg.chirp.shape == "three_segment"
    # the record holds the constant segment (chirp.cw_s of sim.toml: 78 us) after the two ramps
    assert plan.adc.record_length - 2 * plan.adc.ramp_samples == int(plan.adc.fs_hz * 78e-6 + 1e-9)
    assert plan.dsp.cw_samples == plan.adc.cw_samples and plan.dsp.hold_profile is not None


@pytest.mark.parametrize("distance_m, velocity_mps, shape", [(1.5, 0.0, "three_segment"),
                                                            (3.0, 0.25, "three_segment"),
                                                            (2.2, -0.3, "three_segment"), (2.5, 0.2, "triangle")])
def test_a_sweep_task_and_a_scan_of_its_pixel_give_the_same_points(tmp_path, distance_m, velocity_mps, shape):
    task = _task(distance_m, velocity_mps, shape)
    tf = task_frame(task, _bench_rng(task), _bench_noise(task))
    dsp = tf.plan.dsp
    assert (dsp.cw_samples > 0) == (shape == "three_segment")
    scan, meta = _scan_points(task, tf, tmp_path)
    # the same plan: rate, record, band and DSP settings as the scan's sidecar reports them
    assert meta["adc"]["sample_rate_hz"] == tf.plan.adc.fs_hz
    assert meta["adc"]["record_length"] == tf.plan.adc.record_length
    assert meta["dsp"] == dsp.sidecar(tf.plan.phase_noise, meta["dsp"]["path"])     # and the DSP path it took
    row, col = tf.pixel
    optics = task.point.profile.optics(task.point.cfg.lens, task.point.cfg.chirp.wavelength_m)
    sweep = frame_points(tf.result, np.array([[row, col]]), np.zeros(1), optics.directions(np.array([row]),
                         np.array([col])), delay_s=dsp.measurement_delay_s(task.point.cfg.scan.averages))
    assert len(scan) == len(sweep) >= 1
    for name in ("valid", "return_index", "row", "col", "flags"):
        assert np.array_equal(scan[name], sweep[name]), name
    assert scan["valid"][0]
    # the truth: a plane at distance_m along the beam, moving at velocity_mps (receding positive)
    assert abs(sweep["range"][0] - tf.hits.range_m[0]) < 1e-3
    assert abs(sweep["velocity"][0] - velocity_mps) < 5e-3
    # the same points, same noise draw included: another draw would move the range by about the CRLB
    # (measured errors against the truth: 26-87 um here). What differs is the AWG's code rounding
    # (int16 codes: +-66 kHz, 38 kHz rms, of optical frequency per drive sample, the ramps' slope
    # unchanged to 2e-8): a beat phase wobble of 2 pi tau x 38 kHz ~ 5 mrad that moved the ranges by
    # <= 4 um, the velocities by <= 2.3 um/s, the noise floor (SNR) by <= 0.36 dB, the intensity by < 0.1 %
    crlb = crlb_range_m(float(tf.hits.amplitude_v[0]), tf.noise_asd_v_per_rthz, tf.plan.adc.fs_hz, dsp.n_used,
                        dsp.chirp_rate_hz_per_s, task.point.cfg.scan.averages)
    assert 10e-6 < 0.5 * crlb
    np.testing.assert_allclose(scan["range"], sweep["range"], rtol=0, atol=10e-6)
    np.testing.assert_allclose(scan["velocity"], sweep["velocity"], rtol=0, atol=10e-6)
    np.testing.assert_allclose(scan["intensity"], sweep["intensity"], rtol=3e-3)
    np.testing.assert_allclose(scan["snr_db"], sweep["snr_db"], rtol=0, atol=1.0)


def test_a_sweep_task_whose_beat_clips_gives_no_valid_point_as_a_scan():
    # a bright plate at 0.5 m into a 50 mV digitizer range: every record clips. A scan refuses such a
    # pixel's points (lidard.raw.points, flag CLIPPED); the sweep must too, or the clipping's harmonics
    # (which the harmonic screen leaves to this rule: adc.sfdr_dbc is the unclipped receiver's) count
    # as ranged points at 2x / 3x the range. Control: the same plate into the 1 V range does not clip.
    from lidard.dsp.detect.gate import PointFlag
    grid = {"scan.max_range_m": 4.0, "link.tx_power_w": 0.1}
    raw = {"sweep": {"seeds": 1, "trials_per_task": 8}, "target": {"distances_m": [0.5], "reflectivity": 0.9},
           "grid": {**grid, "adc.input_range_v": [0.05, 1.0]}}
    clipped, clean = (task_frame(t).result for t in expand_sweep(raw).tasks)
    assert not (clipped.valid & clipped.present).any()
    assert np.all(clipped.flags[clipped.present] & PointFlag.CLIPPED)
    assert (clean.valid & clean.present).any(axis=1).all()
    assert not np.any(clean.flags & PointFlag.CLIPPED)
