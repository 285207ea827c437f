"""A range record is tied to the phase-noise compensation mode its plates were measured in: the
compensation subtracts the monitor's phase, deterministic chirp residual included, so the same target
reads another range in the other mode (docs/measured/26_range_linearity.md). A scan in the other mode
does not use the record (``calibrated.range`` false, with the reason); a fit of plates of both modes is
refused, naming them."""

from __future__ import annotations

import json

import pytest

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument.calibration.procedures import scan_phase_noise
from lidard.instrument.calibration.range import CalibrationRefused
from lidard.instrument.calibration.setup import calibration_setup, mode_differs, select
from lidard.instrument.types import ScanRequest
from lidard.jobs.calibrations import fit_range
from lidard.store import Store
from lidard.store import CalibrationRecord
from tests.helpers.cli import run
from tests.helpers.fakes import FakeInstrument

SIM = CONFIG_DIR / "sim.toml"


def test_auto_mode_follows_the_gate_against_twice_the_monitor_delay():
    cfg = load_config(SIM)       # auto, 200 ns monitor: on from a 60 m gate (400 ns round trip)
    assert scan_phase_noise(cfg, ScanRequest(max_range_m=59.0), 200e-9) == "off"
    assert scan_phase_noise(cfg, ScanRequest(max_range_m=61.0), 200e-9) == "on"
    assert scan_phase_noise(cfg, ScanRequest(max_range_m=2.0, phase_noise_compensation="on"), 200e-9) == "on"


def test_select_skips_a_range_record_of_the_other_mode():
    setup = calibration_setup(load_config(SIM))["range"]

    def rec(i, mode):
        inputs = {"setup": setup.as_dict(), **({"phase_noise_compensation": mode} if mode else {})}
        return CalibrationRecord(f"r{i}", "range", float(i), None, inputs, {}, {})
    newest_first = [rec(3, "on"), rec(2, "off"), rec(1, None)]
    assert select(newest_first, setup, "on")[0].id == "r3"
    assert select(newest_first, setup, "off")[0].id == "r2"
    assert select(newest_first, setup)[0].id == "r3"                 # no mode asked: any
    got, why = select(newest_first[:1], setup, "off")
    assert got is None and why == ("range calibration r3 not used: its plates were measured with phase-noise "
                                   "compensation on, this scan has it off (scan.phase_noise_compensation; "
                                   "measure plates in this scan's mode)")
    assert select(newest_first[2:], setup, "off")[0].id == "r1"      # a record that names no mode: any scan
    assert mode_differs({"phase_noise_compensation": "off"}, "off") is None


def _plate(known_m, mode):
    # raw = known range x 1.001 + 20 mm: the fit finds tau_eff = tau_nom / 1.001 (ranges scale as 1 / tau)
    return {"known_m": known_m, "known_range_m": known_m, "raw_range_m": known_m * 1.001 + 0.02, "sem_m": 1e-5,
            "pixel_std_m": 1e-4, "n": 36, "delay_s": 200e-9, "temperature_c": 25.0, "phase_noise_compensation": mode}


def test_a_fit_of_plates_in_both_modes_is_refused_naming_them(tmp_path):
    st = Store(tmp_path / "data")
    try:
        ids = [st.geometry.add_range_measurement(_plate(d, m))["id"] for d, m in ((0.8, "off"), (5.0, "off"), (45.0, "on"))]
        with pytest.raises(CalibrationRefused, match=f"both phase-noise compensation modes.*on: {ids[2]} \\(45 m\\)"):
            fit_range(st, 200e-9)
        st.geometry.remove_range_measurements([ids[2]])
        st.geometry.add_range_measurement(_plate(20.0, "off"))
        rec = fit_range(st, 200e-9)
        assert rec.inputs["phase_noise_compensation"] == "off"
        assert rec.fitted["delay_s"] == pytest.approx(200e-9 / 1.001, rel=1e-7)
    finally:
        st.close()


def test_a_scan_in_the_other_mode_is_not_range_calibrated(capsys, monkeypatch, tmp_path):
    from lidard.cli import base as cli_base
    inst = FakeInstrument()
    inst.cfg = load_config(SIM)            # the mode is resolved from the scan's configuration
    monkeypatch.setattr(cli_base, "open_instrument", lambda cfg, **kw: inst)
    data = tmp_path / "data"
    st = Store(data)
    setup = calibration_setup(load_config(SIM))
    rng = st.geometry.save("range", temperature_c=25.0,
                                       inputs={"setup": setup["range"].as_dict(), "phase_noise_compensation": "off"},
                                       residuals={}, fitted={"delay_s": 201.2e-9, "zero_offset_m": 0.02})
    st.close()
    scan = ["scan", "--sim", "--data-dir", str(data), "--rows", "2:4", "--json"]
    code, out, err = run(capsys, *scan, "--phase-noise", "off")
    assert code == 0, err
    assert json.loads(out)["calibrated"]["range"] is True and inst.applied.delay_s == 201.2e-9
    code, out, err = run(capsys, *scan, "--phase-noise", "on")
    assert code == 0, err
    got = json.loads(out)
    assert got["calibrated"]["range"] is False and inst.applied.delay_s is None
    assert f"range calibration {rng.id} not used: its plates were measured with phase-noise compensation off, " \
           "this scan has it on" in got["uncalibrated_reason"]
    assert "warning: uncalibrated range" in err


def test_stated_range_uncertainty_matches_the_spread_of_refits():
    """The sidecar's ``geometry.range_uncertainty_m`` (AppliedCalibrations.range_uncertainty_m): the 1-sigma
    range error a fit leaves at a range, from the fit's standard errors and their covariance. Against the
    spread of the errors of 1000 fits of noisy plates at 0.8 / 1.1 / 1.4 m (the factory plates): at 150 m
    (scale-dominated) and at 1.1 m (the plates' centre, where the covariance cancels most of it)."""
    import numpy as np

    from lidard.instrument.calibration.applied import AppliedCalibrations
    from lidard.instrument.calibration.range import PlateMeasurement
    from lidard.instrument.calibration.range import fit_range as fit_plates
    tau_nom, tau_true, z0, sem = 200e-9, 200.8e-9, 0.031, 30e-6
    rng = np.random.default_rng(5)
    errs, stated = {150.0: [], 1.1: []}, {}
    for _ in range(1000):
        ms = [PlateMeasurement(known_m=d, known_range_m=d, raw_range_m=(d + z0) * tau_nom / tau_true
                               + rng.normal(0, sem * tau_nom / tau_true), sem_m=sem, pixel_std_m=3e-4, n=36,
                               delay_s=tau_nom) for d in (0.8, 1.1, 1.4)]
        f = fit_plates(ms, tau_nom, p_min=0.0)
        for r, e in errs.items():   # a scan at true range r reads (r + z0) tau_fit / tau_true - z0_fit
            e.append((r + z0) * f.delay_s / tau_true - f.zero_offset_m - r)
    rec = CalibrationRecord("r", "range", 0.0, None, {}, f.fitted(), {})
    applied = AppliedCalibrations.from_records(rec)
    for r, e in errs.items():
        stated[r] = applied.range_uncertainty_m(r)
        assert stated[r] == pytest.approx(float(np.std(e)), rel=0.08), (r, stated[r], np.std(e))
    assert stated[150.0] > 50 * stated[1.1]
    meta = applied.meta(tau_nom, 150.0)
    assert meta["range_uncertainty_at_m"] == 150.0 and meta["range_uncertainty_m"] == stated[150.0]
    assert AppliedCalibrations().meta(tau_nom, 150.0)["range_uncertainty_m"] is None     # uncalibrated: none
