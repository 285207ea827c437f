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
from lidard.store_calibrations import CalibrationRecord
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
        ids = [st.add_range_measurement(_plate(d, m))["id"] for d, m in ((0.8, "off"), (5.0, "off"), (45.0, "on"))]
        with pytest.raises(CalibrationRefused, match=f"both phase-noise compensation modes.*on: {ids[2]} \\(45 m\\)"):
            fit_range(st, 200e-9)
        st.remove_range_measurements([ids[2]])
        st.add_range_measurement(_plate(20.0, "off"))
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
    rng = st.save_geometry_calibration("range", temperature_c=25.0,
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
