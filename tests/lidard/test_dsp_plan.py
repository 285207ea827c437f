"""The signal path's one constructor (lidard.instrument.dsp_plan) and the FrameDsp record a raw capture
keeps: what the configuration, the ADC plan and the calibration each decide, checked against the
chirp's arithmetic, and a record that rebuilds exactly the DSP it came from."""

from __future__ import annotations

import json

import pytest

from lidard.config import load_config
from lidard.dsp.frame import FrameDsp
from lidard.instrument.dsp_plan import AdcPlan, DspCalibration, adc_plan, frame_dsp, plan_signal
from lidard.raw.capture import RawCaptureError
from lidard.raw.replay import replay_dsp

HOLD = {"t0_s": 160e-6, "dt_s": 1e-7, "nu_hz": [0.0, 1e6, 2e6]}


def _cfg(**env):
    return load_config("config/sim.toml", environ=env)


def test_the_plan_follows_the_chirp_the_band_and_the_calibration():
    cfg = _cfg()
    cal = DspCalibration(mzi_delay_s=201e-9, iq_gain=1.05, iq_phase_rad=0.02, hold_profile=HOLD)
    sig = plan_signal(cfg, cal, max_range_m=2.0, max_speed_mps=10.0)
    fs = sig.adc.fs_hz
    # the record: up + down ramp, then the constant segment's whole samples (chirp.cw_s of sim.toml: 78 us)
    assert sig.adc.ramp_samples == round(fs * cfg.chirp.ramp_s)
    assert sig.adc.cw_samples == int(fs * 78e-6 + 1e-9) == sig.dsp.cw_samples > 0
    # the band holds the beat of 2 m plus the Doppler of 10 m/s, oversampled (adc.oversample = 2.5)
    beat_hz = 2 * cfg.chirp.rate_hz_per_s * 2.0 / 299_792_458.0 + 2 * 10.0 / cfg.chirp.wavelength_m
    assert fs >= 2.5 * beat_hz
    d = sig.dsp
    assert (d.max_range_m, d.max_speed_mps, d.pfa, d.max_returns, d.window) == (2.0, 10.0, cfg.scan.pfa,
                                                                              cfg.scan.max_returns, cfg.scan.window)
    # a real receiver (adc.iq false) keeps no imbalance; the hold's drift reaches the three-segment DSP
    assert d.hold_profile == HOLD and not d.iq
    # 40 MS/s decimated from the 1 GS/s core: the decimation filter's alias-free band caps the gate
    assert d.alias_free_hz is not None and d.alias_free_hz < fs / 2
    # phase noise: "auto" is off at 2 m (round trip << 2 monitor delays), "on" samples the MZI beat too
    assert not sig.phase_noise and sig.mzi_delay_s == 201e-9
    on = plan_signal(cfg, cal, max_range_m=2.0, max_speed_mps=10.0, phase_noise="on")
    assert on.phase_noise and on.adc.fs_hz > fs


def test_the_triangle_has_no_constant_segment_and_ignores_a_hold_profile():
    cfg = _cfg(LIDARD__CHIRP__SHAPE="triangle")
    sig = plan_signal(cfg, DspCalibration(200e-9, hold_profile=HOLD), max_range_m=2.0)
    assert sig.adc.record_length == 2 * sig.adc.ramp_samples and sig.dsp.cw_samples == 0
    assert sig.dsp.hold_profile is None and sig.dsp.max_speed_mps == cfg.scan.max_speed_mps


def test_an_iq_receiver_takes_the_calibrated_imbalance():
    cfg = load_config("config/sim_iq.toml")
    dsp = frame_dsp(cfg, adc_plan(cfg, 2.0), DspCalibration(200e-9, iq_gain=1.06, iq_phase_rad=-0.05),
                    max_range_m=2.0, max_speed_mps=cfg.scan.max_speed_mps, estimator="jacobsen")
    assert dsp.iq and (dsp.iq_gain, dsp.iq_phase_rad, dsp.estimator) == (1.06, -0.05, "jacobsen")


def test_a_record_rebuilds_the_same_dsp_and_names_what_it_does_not_know():
    cfg = _cfg()
    dsp = frame_dsp(cfg, AdcPlan(40e6, 3200, 9520, 16), DspCalibration(200e-9, hold_profile=HOLD),
                    max_range_m=2.0, max_speed_mps=10.0)
    rec = json.loads(json.dumps(dsp.to_record()))          # what a capture's attributes hold
    assert FrameDsp.from_record(rec) == dsp
    assert FrameDsp.from_record(rec, pfa=1e-6).pfa == 1e-6
    with pytest.raises(ValueError, match=r"\['speed_prior'\] are not FrameDsp settings"):
        FrameDsp.from_record({**rec, "speed_prior": 1.0})
    attrs = {"dsp": {**rec, "speed_prior": 1.0}, "adc": {"lsb_v": 1.0}}
    with pytest.raises(RawCaptureError, match="speed_prior"):
        replay_dsp(attrs)


@pytest.mark.parametrize("sfdr", ["25", "55"])
def test_the_receivers_sfdr_sets_the_harmonic_screen_of_every_front_end(sfdr):
    # adc.sfdr_dbc reaches the per-ramp detector the scan, the phase-noise front end and the spectrum
    # view share (FrameDsp.cfar), and a capture's record keeps it for its replays
    cfg = _cfg(LIDARD__ADC__SFDR_DBC=sfdr)
    dsp = plan_signal(cfg, DspCalibration.nominal(cfg), max_range_m=2.0).dsp
    assert dsp.sfdr_dbc == float(sfdr) == dsp.cfar.harmonic_ratio_db
    assert FrameDsp.from_record(json.loads(json.dumps(dsp.to_record()))).cfar.harmonic_ratio_db == float(sfdr)


def test_a_capture_recorded_before_the_sfdr_replays_with_the_screen_its_scan_ran():
    # a record without sfdr_dbc was written when the harmonic screen sat at a fixed 15 dB: its replay
    # runs that, not today's default (a replay is the DSP its scan built)
    cfg = _cfg()
    rec = plan_signal(cfg, DspCalibration.nominal(cfg), max_range_m=2.0).dsp.to_record()
    assert FrameDsp.from_record(rec).sfdr_dbc == cfg.adc.sfdr_dbc == 40.0
    old = {k: v for k, v in rec.items() if k != "sfdr_dbc"}
    assert FrameDsp.from_record(old).cfar.harmonic_ratio_db == 15.0
    assert FrameDsp.from_record(old, sfdr_dbc=30.0).sfdr_dbc == 30.0
