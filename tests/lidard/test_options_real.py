"""Every option acts (issue 11 item 2): [scan] defaults fill requests, USB timeouts reach the drivers,
adc.bits / adc.bandwidth_hz configure the digitizer, adc.iq = true and a laser current above the
preset's maximum are refused, and a low HV is named at bring-up and by the self-test.

Expected values come from the documented relations (config.Adc: record bits = core bits +
log2(sqrt(max rate / rate)); selftest_analysis: HV below the profile's pull-in), not from the code.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidard.api.schemas import check_scan_body
from lidard.config import ConfigError, ScanDefaults, load_config
from lidard.instrument import InstrumentError, open_instrument
from lidard.instrument.acquisition import AcquisitionPlan
from tests.helpers.fakes import FakeInstrument

REPO = Path(__file__).resolve().parents[2]
SIM = REPO / "config" / "sim.toml"
CUSTOM = ScanDefaults(averages=3, max_range_m=7.5, pattern="serpentine")


# ----------------------------------------------------------------------------- [scan] defaults
def test_a_request_that_leaves_fields_out_takes_the_config_scan_defaults():
    req = check_scan_body({}).to_request(CUSTOM)
    assert (req.pattern, req.averages, req.max_range_m) == ("serpentine", 3, 7.5)
    # given fields win; a pixel list alone means the pixel pattern
    req = check_scan_body({"averages": 2, "pixels": [[0, 0]]}).to_request(CUSTOM)
    assert (req.pattern, req.averages, req.max_range_m) == ("pixels", 2, 7.5)


def test_post_scans_without_fields_uses_the_daemon_config(make_client):
    cfg = load_config(SIM, environ={"LIDARD__SCAN__AVERAGES": "4", "LIDARD__SCAN__MAX_RANGE_M": "6.0",
                                    "LIDARD__SCAN__PATTERN": "serpentine"})
    inst = FakeInstrument()
    c = make_client(inst, cfg=cfg)
    sid = c.post("/scans", json={}).json()["id"]
    c.app.state.worker.wait(sid, 20.0)
    req = inst.requests[-1]
    assert (req.pattern, req.averages, req.max_range_m) == ("serpentine", 4, 6.0)


def test_lidarctl_scan_sim_request_takes_the_config_defaults():
    from lidard.cli.scan import sim_request
    cfg = load_config(SIM, environ={"LIDARD__SCAN__AVERAGES": "5", "LIDARD__SCAN__MAX_RANGE_M": "3.0"})
    req = sim_request({"formats": ["ply"]}, cfg)
    assert (req.averages, req.max_range_m, req.pattern) == (5, 3.0, cfg.scan.pattern)


# ----------------------------------------------------------------------------- refused at load
def test_adc_iq_true_is_refused_by_name():
    with pytest.raises(ConfigError, match=r"adc\.iq.*I/Q"):
        load_config(SIM, environ={"LIDARD__ADC__IQ": "true"})


def test_a_laser_current_above_the_preset_maximum_is_refused():
    with pytest.raises(ConfigError, match=r"laser_current_ma.*250 mA.*200 mA"):
        load_config(SIM, environ={"LIDARD__DEVICES__CONTROLLER__LASER_CURRENT_MA": "250",
                                  "LIDARD__DEVICES__CONTROLLER__MAX_LASER_CURRENT_MA": "300"})


@pytest.mark.parametrize("core, fs, expect", [
    (8, 1e9 / 4**2, 8 + 2 + 4),     # 16x decimation: log2(sqrt(16)) = 2 bits of gain, + 4 guard bits
    (8, 1e9 / 2**3, 8 + 2 + 4),     # 8x: 1.5 bits, to the nearest bit 2
    (8, 1e9, 8),                    # full rate: the core's own bits
    (8, 5e6, 16),                   # 200x: 8 + 4 + 4, capped at the 16-bit record format
])
def test_record_resolution_is_core_bits_plus_the_decimation_gain(core, fs, expect):
    cfg = load_config(SIM, environ={"LIDARD__ADC__BITS": str(core)})
    assert cfg.adc.record_bits(fs) == expect


# ----------------------------------------------------------------------------- on the bench
@pytest.fixture(scope="module")
def inst():
    cfg = load_config(SIM, environ={"LIDARD__DEVICES__AWG__TIMEOUT_S": "0.75",
                                    "LIDARD__DEVICES__DIGITIZER__TIMEOUT_S": "1.25",
                                    "LIDARD__ADC__BITS": "10", "LIDARD__ADC__BANDWIDTH_HZ": "2e6",
                                    "LIDARD__DEVICES__CONTROLLER__MAX_LASER_CURRENT_MA": "300"})
    i = open_instrument(cfg, bench="embedded")
    yield i
    i.close()


def test_usb_timeouts_and_the_preset_current_limit_reach_the_drivers(inst):
    assert inst.registry["awg"]._timeout_ms == 750
    assert inst.registry["digitizer"]._timeout_ms == 1250
    # the controller's limit is the lower of devices.controller (300) and the laser preset (200)
    assert inst.registry["controller"].limits.max_laser_current_ma == 200.0


def test_adc_bits_and_bandwidth_configure_the_digitizer(inst):
    fs = 1e9 / 4             # 4x decimation: exactly 1 bit of gain
    plan = AcquisitionPlan(np.array([[0, 0]]), 1, ("beat",), fs, 64, 16)
    acq = inst.acquisition.ready(plan)
    try:
        got = inst.registry["digitizer"].config()
    finally:
        inst.acquisition.abort(acq)
    assert got.resolution_bits == 10 + 1 + 4                    # 10-bit core + 1 gain + 4 guard bits
    assert got.bandwidth_hz == 2_000_000


def test_a_low_hv_is_refused_at_bring_up_and_named_by_the_selftest(inst):
    profile = inst.profile
    low = profile.pull_in_v - 2.0
    inst.safety.hv_v = low
    try:
        with pytest.raises(InstrumentError, match=rf"HV 3\d\.\d\d V is below .*pull-in voltage {profile.pull_in_v:.2f} V"):
            inst.safety.bring_up()
        assert not inst.registry["controller"].hv_is_on()    # brought down again
        rep = inst.selftest()
    finally:
        inst.safety.hv_v = profile.actuation_v
    assert rep["ok"] is False
    assert rep["hv_v"] == pytest.approx(low, abs=0.1)
    assert f"pull-in voltage {profile.pull_in_v:.2f} V" in rep["hv_problem"]
    assert inst.selftest()["hv_problem"] is None                       # at the profile's actuation
