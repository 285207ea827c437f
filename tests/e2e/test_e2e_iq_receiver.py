"""End to end (issue 14 item 2): the coherent (I/Q) receiver on the simulated bench.

config/sim_iq.toml: a 90-degree hybrid and two photodiodes on digitizer channels beat_i / beat_q, the
triangle alone, no speed prior. The bench's hybrid has a hidden imbalance (0.8 dB, 6 degrees here,
drawn from [sim.tolerances] in general). Checked on a 16 x 32 pixel frame with three moving boxes and a
static wall behind them: a box APPROACHING at 4 m/s at 1 m (its Doppler, 5.2 MHz, is larger than its
range beat, 0.72 MHz: a single photodiode's beat would fold), one receding at 2.5 m/s at 1.5 m, the
near box receding at 1 m/s at 0.4 m:

* before calibration the sidecar says calibrated.iq = false; the images the hybrid makes are not points;
* the calibration (lidarctl calibration iq / run_iq_calibration) finds the hidden gain and phase;
* after it every point is within 1 mm RMS of the truth moved to the point's own t, and within
  0.05 m/s of the true radial velocity, with the right sign, on every box and the wall.
"""

import math
import threading

import numpy as np
import pytest

from lidard.config import load_config
from lidard.instrument import ScanRequest, open_instrument
from lidard.instrument.calibration.procedures import run_iq_calibration
from lidard.instrument.calibration.range import CalibrationRefused
from tests.helpers.tolerances import NOMINAL_ENV

pytestmark = pytest.mark.slow  # an I/Q bench calibrated and scanning

GAIN_DB, PHASE_DEG = 0.8, 6.0
# only the hybrid's tolerances on (at these bounds): the ranges are scored uncalibrated otherwise
HYBRID_ENV = {"LIDARD__SIM__TOLERANCES__ENABLED": "true", "LIDARD__SIM__TOLERANCES__DRAW": "false",
              "LIDARD__SIM__TOLERANCES__HYBRID_GAIN_DB": str(GAIN_DB),
              "LIDARD__SIM__TOLERANCES__HYBRID_PHASE_DEG": str(PHASE_DEG),
              **{f"LIDARD__SIM__TOLERANCES__{k}": "0" for k in
                 ("MZI_DELAY_REL", "ZERO_OFFSET_M", "FOCAL_REL", "DECENTRE_PX", "ROTATION_DEG", "K1", "TEC_DRIFT_C")}}
# (x, z) of each box centre, its radial (z) speed; receding positive
BOXES = [((0.027, 1.0), -4.0), ((0.0, 1.5), 2.5), ((-0.0115, 0.4), 1.0)]
WALL_M = 3.0
FRAME = dict(pattern="roi", rows=(56, 72), cols=(48, 80))


def scene() -> dict:
    boxes = [{"kind": "box", "center": [x, 0.0, z], "size": [0.02 if z > 0.5 else 0.005, 0.3, 0.05],
              "reflectivity": 0.8, "velocity": [0.0, 0.0, v]} for (x, z), v in BOXES]
    return {"target": boxes + [{"kind": "plane", "point": [0.0, 0.0, WALL_M], "normal": [0.0, 0.0, -1.0],
                                "reflectivity": 0.9}]}


@pytest.fixture(scope="module")
def iq_bench():
    cfg = load_config("config/sim_iq.toml", environ=HYBRID_ENV)
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    bench = inst._on_close.__self__
    cal = inst.linearize()
    yield inst, bench, cal
    inst.close()


def _scan(inst, cal):
    inst.set_scene(scene())
    return inst.run_scan(ScanRequest(max_range_m=5.0, **FRAME), lambda p: None, threading.Event(), cal)


def _score(bench, res):
    pts = res.points[res.points["valid"] == 1]
    truth = bench.ground_truth(pts["row"], pts["col"], pts["t"])
    d = bench.world.optics.directions(pts["row"], pts["col"])
    groups = [(np.abs(truth - z) < 0.3, v) for (_, z), v in BOXES] + [(np.abs(truth - WALL_M) < 0.01, 0.0)]
    return pts, truth, d, groups


def test_iq_receiver_ranges_folded_and_receding_targets_after_its_calibration(iq_bench):
    inst, bench, cal = iq_bench
    truth = bench.truth()
    assert truth.iq_gain == pytest.approx(10 ** (GAIN_DB / 20)) and truth.iq_phase_rad == pytest.approx(math.radians(PHASE_DEG))

    before = _scan(inst, cal)
    assert before.meta["calibrated"]["iq"] is False and before.meta["dsp"]["receiver"] == "iq"
    assert before.meta["adc"]["sample_rate_hz"] > 0
    # the hybrid's images (-23 dB) are not points: every valid point lies on a surface
    pts, t_before, _, _ = _score(bench, before)
    assert len(pts) > 300 and np.max(np.abs(pts["range"] - t_before)) < 2e-3

    run = run_iq_calibration(inst, linearization=cal, max_range_m=5.0)
    fit = run.fit
    assert fit.tones >= 128
    assert abs(fit.gain - truth.iq_gain) <= max(5 * fit.gain_sem, 2e-3)
    assert abs(fit.phase_rad - truth.iq_phase_rad) <= max(5 * fit.phase_sem_rad, math.radians(0.1))
    assert fit.irr_before_db == pytest.approx(10 * math.log10(
        abs(1 - truth.iq_gain * np.exp(1j * truth.iq_phase_rad)) ** 2
        / abs(1 + truth.iq_gain * np.exp(1j * truth.iq_phase_rad)) ** 2), abs=0.2)

    after = _scan(inst, cal)
    assert after.meta["calibrated"]["iq"] is True
    assert after.meta["geometry"]["iq_gain"] == pytest.approx(fit.gain)
    pts, t_after, d, groups = _score(bench, after)
    err = pts["range"] - t_after
    assert np.sqrt(np.mean(err ** 2)) <= 1e-3
    for sel, v in groups:
        assert sel.sum() >= 10, f"target moving at {v} m/s ranged on {sel.sum()} pixels"
        assert np.sqrt(np.mean(err[sel] ** 2)) <= 1e-3
        v_true = d[sel] @ np.array([0.0, 0.0, v])
        assert np.max(np.abs(pts["velocity"][sel] - v_true)) <= 0.05
        if v:
            assert np.all(np.sign(pts["velocity"][sel]) == np.sign(v))
    # nothing in the frame but the boxes and the wall
    assert sum(int(s.sum()) for s, _ in groups) == len(pts)


def test_iq_calibration_refuses_an_empty_view(iq_bench):
    inst, _, cal = iq_bench
    inst.set_scene({"target": []})
    with pytest.raises(CalibrationRefused, match="point the receiver at a target"):
        run_iq_calibration(inst, linearization=cal)


def test_iq_calibration_is_refused_on_a_single_photodiode():
    cfg = load_config("config/sim.toml", environ=NOMINAL_ENV)
    inst = open_instrument(cfg, scene_path="config/scenes/empty.toml", bench="embedded")
    try:
        assert inst.iq_receiver is False
        with pytest.raises(CalibrationRefused, match="adc.iq = false"):
            run_iq_calibration(inst)   # refused before it linearizes
    finally:
        inst.close()


def test_an_iq_capture_replays_to_the_same_points_with_its_correction(iq_bench, tmp_path):
    """The raw capture keeps beat_i and beat_q; its dsp settings carry the imbalance correction, so a
    replay gives the scan's points bit for bit."""
    from lidard.raw import RawCapture, reprocess
    inst, _, cal = iq_bench
    inst.set_scene(scene())
    run_iq_calibration(inst, linearization=cal, max_range_m=5.0)
    path = tmp_path / "raw.zarr"
    res = inst.run_scan(ScanRequest(max_range_m=5.0, pattern="roi", rows=(60, 64), cols=(48, 80)),
                        lambda p: None, threading.Event(), cal, raw_path=path)
    cap = RawCapture(path)
    assert cap.channels == ["beat_i", "beat_q"] and cap.attrs["dsp"]["iq"] is True
    assert cap.attrs["dsp"]["iq_gain"] == pytest.approx(inst.applied.iq_imbalance[0])
    again = reprocess(path)
    assert np.array_equal(again.points, res.points) and again.meta["dsp"]["receiver"] == "iq"
    # the pixel spectrum view of the capture: two-sided, the down ramp in the up ramp's sign, both
    # ramps' detection at the point's own beat (range +- its Doppler share)
    from lidard.raw.spectrum import pixel_spectrum
    p = res.points[res.points["valid"] == 1][0]
    spec = pixel_spectrum(path, int(p["row"]), int(p["col"]))
    assert spec.range_m.min() < 0 < spec.range_m.max()
    doppler_m = 2 * abs(float(p["velocity"])) / inst.cfg.chirp.wavelength_m * 299_792_458.0 / (2 * inst.cfg.chirp.rate_hz_per_s)
    for ramp in ("up", "down"):
        rng = [d["range_m"] for d in spec.detections if d["ramp"] == ramp]
        assert rng and min(abs(abs(r - float(p["range"])) - doppler_m) for r in rng) < 0.02, (ramp, rng, p)


# last in the module: the app's shutdown closes the instrument it was given (the fixture's)
def test_iq_calibration_through_lidarctl_and_the_daemon(iq_bench, capsys, tmp_path):
    """CLI -> REST -> worker -> store: the record, its summary, and scans that say they used it."""
    import json

    from tests.helpers.api import live_server, make_app
    from tests.helpers.cli import run
    inst, bench, _ = iq_bench
    inst.set_scene(scene())
    app = make_app(tmp_path / "data", inst, cfg=inst.cfg, progress_interval_s=0.0)
    with live_server(app) as url:
        code, out, err = run(capsys, "scan", "--url", url, "--rows", "60:62", "--cols", "60:64", "--json")
        assert code == 0, err
        assert json.loads(out)["calibrated"]["iq"] is False
        assert "uncalibrated I/Q receiver" in err
        code, out, err = run(capsys, "calibration", "iq", "--url", url, "--max-range-m", "5", "--json")
        assert code == 0, err
        rec = json.loads(out)
        # within five of the fit's own standard errors (the bound the in-process test uses): a fixed 3e-3
        # was 1.4 sigma at this fit's 2.1e-3 and failed on an honest draw
        assert rec["kind"] == "iq"
        res_ = rec["residuals"]
        assert res_["tones"] >= 128 and res_["gain_sem"] < 5e-3 and res_["phase_sem_rad"] < 5e-3   # a fit, not a shrug
        assert abs(rec["fitted"]["gain"] - bench.truth().iq_gain) <= max(5 * res_["gain_sem"], 2e-3)
        assert abs(rec["fitted"]["phase_rad"] - bench.truth().iq_phase_rad) <= max(5 * res_["phase_sem_rad"],
                                                                                  math.radians(0.1))
        code, out, err = run(capsys, "calibration", "list", "--kind", "iq", "--url", url)
        assert code == 0 and rec["id"] in out and "image" in out
        code, out, err = run(capsys, "scan", "--url", url, "--rows", "60:62", "--cols", "60:64", "--json")
        assert code == 0, err
        s = json.loads(out)
        assert s["calibrated"]["iq"] is True
        assert "uncalibrated I/Q" not in err
        code, out, err = run(capsys, "scans", "show", s["id"], "--url", url)
        assert code == 0 and f"iq {rec['id']}" in out
        code, out, err = run(capsys, "calibration", "iq", "--url", url, "--max-range-m", "-1")
        assert code != 0 and "max_range_m" in err
