"""How the stored range/pointing calibrations reach the points and the linearization (issue 13 item 2)."""

import dataclasses

import numpy as np
import pytest

from lidard.config import load_profile
from lidard.dsp.frame import FrameResult
from lidard.instrument.calibration.applied import AppliedCalibrations
from lidard.instrument.points import points_from
from lidard.instrument.types import ScanRequest
from lidard.jobs import ScanWorker
from lidard.physics.optics import Pointing
from lidard.store import Store
from tests.helpers.fakes import FakeInstrument


def test_points_take_the_zero_offset_off_the_range_and_lie_along_the_calibrated_rays():
    optics = load_profile("fpsa128").optics()
    p = Pointing(focal_scale=1.01, decentre_px=(0.8, -0.3), rotation_rad=0.005, k1=0.1)
    applied = AppliedCalibrations(range_id="r", delay_s=201e-9, zero_offset_m=0.035, pointing_id="p", pointing=p)
    px = np.array([[0, 0], [64, 100]])
    res = FrameResult(present=np.ones((2, 1), bool), valid=np.ones((2, 1), bool),
                      range_m=np.array([[1.0], [2.5]]), velocity_mps=np.zeros((2, 1)), snr_db=np.full((2, 1), 30.0),
                      intensity_v=np.ones((2, 1)))
    pts = points_from(res, applied.optics(optics), px, np.zeros(2), None, applied.zero_offset_m)
    assert pts["range"] == pytest.approx([0.965, 2.465], abs=1e-6)
    # the calibrated ray: antenna position rotated, shifted, scaled by the focal error, distorted (eq. 4-1 + Pointing)
    x, y = optics.antenna_xy_m(px[:, 0], px[:, 1])
    c, s = np.cos(0.005), np.sin(0.005)
    xr, yr = c * x - s * y + 0.8 * optics.pitch_m, s * x + c * y - 0.3 * optics.pitch_m
    u, v = xr / (1.01 * optics.focal_m), yr / (1.01 * optics.focal_m)
    g = 1 + 0.1 * (u * u + v * v)
    d = np.stack([-u * g, -v * g, np.ones(2)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
    assert xyz == pytest.approx(d * np.array([0.965, 2.465])[:, None], abs=2e-6)
    # no calibration: the nominal optics, nothing subtracted
    plain = points_from(res, AppliedCalibrations().optics(optics), px, np.zeros(2))
    assert plain["range"] == pytest.approx([1.0, 2.5])
    assert plain["x"][0] == pytest.approx(optics.directions(0, 0)[0] * 1.0, abs=1e-6)


class DelayFake(FakeInstrument):
    """A fake whose linearization records the delay it targeted, as the real one does."""

    def linearize(self, progress=None):
        cal = super().linearize(progress)
        return dataclasses.replace(cal, meta={"mzi_delay_s": self.monitor_delay_s()})


def test_a_new_range_calibration_makes_the_stored_linearization_stale(tmp_path):
    inst = DelayFake()
    store = Store(tmp_path / "d")
    w = ScanWorker(inst, store, laser="dfb_default", progress_interval_s=0.0)
    w.start()
    try:
        req = ScanRequest(pattern="roi", rows=(0, 1), cols=(0, 2))
        assert w.wait(w.submit_scan(req).id).state == "done"
        assert inst.linearize_calls == 1
        assert w.wait(w.submit_scan(req).id).state == "done"
        assert inst.linearize_calls == 1                        # reused
        rec = store.geometry.save("range", temperature_c=25.0, inputs={}, residuals={},
                                              fitted={"delay_s": 200.9e-9, "zero_offset_m": 0.01})
        done = w.wait(w.submit_scan(req).id)
        assert inst.linearize_calls == 2                        # the ILC's target moved: linearized again
        assert inst.applied.delay_s == 200.9e-9 and done.range_calibration_id == rec.id
        assert store.latest_calibration("dfb_default").meta["mzi_delay_s"] == 200.9e-9
        w.wait(w.submit_scan(req).id)
        assert inst.linearize_calls == 2
    finally:
        w.stop()
        store.close()


def test_records_survive_a_reopened_store_and_nan_becomes_null(tmp_path):
    st = Store(tmp_path / "d")
    m = st.geometry.add_range_measurement({"known_m": 1.0, "temperature_c": float("nan"), "sem_m": 1e-5})
    rec = st.geometry.save("range", temperature_c=float("nan"), inputs={"x": [1.0]},
                                       fitted={"delay_s": 2e-7, "zero_offset_m": 0.0}, residuals={"p_value": float("nan")})
    st.close()
    st = Store(tmp_path / "d")      # a daemon restart between `range add` and `range fit` loses nothing
    try:
        assert [x["id"] for x in st.geometry.range_measurements()] == [m["id"]]
        assert st.geometry.range_measurements()[0]["temperature_c"] is None
        got = st.geometry.get(rec.id)
        assert got.residuals == {"p_value": None} and got.temperature_c is None
        assert st.geometry.latest("range").id == rec.id and st.geometry.latest("pointing") is None
        assert st.geometry.remove_range_measurements() == 1 and st.geometry.range_measurements() == []
        with pytest.raises(ValueError, match="calibration kind 'plate'"):
            st.geometry.save("plate", temperature_c=None, inputs={}, fitted={}, residuals={})
    finally:
        st.close()
