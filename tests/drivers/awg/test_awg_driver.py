"""AwgDriver <-> SimAwg round trips through real pyusb calls, in-process and over the TCP bridge."""

import numpy as np
import pytest

from drivers.awg.driver import AwgError
from drivers.usbtmc import DeviceDisconnected, DeviceStall, DeviceTimeout, InvalidArgument


def test_identify_and_usb_strings(awg_pair):
    drv, sim = awg_pair
    ident = drv.identify()
    assert (ident.manufacturer, ident.model, ident.serial) == ("lidard-sim", "AWG-16", "SIM0001")
    assert drv._dev.serial_number == "SIM0001"


def test_every_setting_round_trips(awg_pair):
    drv, sim = awg_pair
    drv.reset()
    drv.set_sample_rate(250e6)
    drv.set_amplitude(0.75)
    drv.set_offset(-0.25)
    drv.set_trigger_external(True)
    drv.output(True)
    assert sim.sample_rate_hz == 250e6 and drv.sample_rate() == 250e6
    assert sim.amplitude_v == 0.75 and drv.amplitude() == 0.75
    assert sim.offset_v == -0.25 and drv.offset() == -0.25
    assert sim.trigger_external is True and sim.output_on is True and drv.output_on()
    drv.set_trigger_external(False)
    drv.output(False)
    assert sim.trigger_external is False and not drv.output_on()
    drv.reset()
    assert sim.sample_rate_hz == 1e9 and sim.amplitude_v == 1.0 and not sim.output_on


def test_upload_normalized_waveform_reaches_dac_exactly(awg_pair):
    drv, sim = awg_pair
    drv.set_amplitude(0.5)
    drv.set_offset(0.1)
    n = 4000
    s = np.sin(2 * np.pi * 3 * np.arange(n) / n)
    drv.upload_waveform(s)
    assert drv.waveform_points() == n
    volts, fs = sim.drive_volts()
    # DAC model: V = offset + amplitude * round(s*32767)/32767 -> error <= amplitude/(2*32767)
    assert np.max(np.abs(volts - (0.1 + 0.5 * s))) <= 0.5 / (2 * 32767) + 1e-15
    assert fs == sim.sample_rate_hz


def test_upload_in_volts_sets_amplitude_and_offset(awg_pair):
    drv, sim = awg_pair
    v = 1.2 + 0.3 * np.cos(np.linspace(0, 2 * np.pi, 1001))  # spans 0.9 .. 1.5 V
    drv.upload_waveform(v, units="volts")
    assert sim.amplitude_v == pytest.approx(0.3)
    assert sim.offset_v == pytest.approx(1.2)
    volts, _ = sim.drive_volts()
    assert np.max(np.abs(volts - v)) < 0.3 / 32767


def test_volts_upload_after_a_far_offset_goes_through_offset_zero(awg_pair):
    # old setting 4.0 V +- 0.5 V, new 0 V +- 4.5 V: both fit the 5 V output stage, but the new amplitude
    # with the old offset (8.5 V) does not, so a naive amplitude-then-offset order is refused (-222)
    drv, sim = awg_pair
    drv.upload_waveform(4.0 + 0.5 * np.sin(np.linspace(0, 2 * np.pi, 501)), units="volts")
    assert sim.offset_v == pytest.approx(4.0) and sim.amplitude_v == pytest.approx(0.5)
    v = 4.5 * np.sin(np.linspace(0, 2 * np.pi, 501))
    drv.upload_waveform(v, units="volts")
    assert sim.offset_v == pytest.approx(0.0, abs=1e-9) and sim.amplitude_v == pytest.approx(4.5, rel=1e-6)
    volts, _ = sim.drive_volts()
    assert np.max(np.abs(volts - v)) < 4.5 / 32767 * 2


def test_large_waveform_is_split_into_several_transfers(awg_pair):
    drv, sim = awg_pair
    rng = np.random.default_rng(7)
    s = rng.uniform(-1, 1, 700_000)  # 1.4 MB of codes > 1 MiB chunk
    drv.upload_waveform(s)
    assert sim.codes.size == 700_000
    assert np.array_equal(sim.codes, np.rint(s * 32767).astype(np.int16))


def test_device_error_names_the_command(awg_pair):
    drv, sim = awg_pair
    with pytest.raises(AwgError) as ei:
        drv.set_sample_rate(5e12)
    assert ei.value.code == -222
    assert "SOUR:FREQ:SAMP" in str(ei.value) and "awg" in str(ei.value)
    assert sim.sample_rate_hz == 1e9  # refused value not applied
    assert drv.errors() == []  # the driver drained the queue


def test_error_queue_order_undefined_header_and_overflow(awg_pair):
    drv, sim = awg_pair
    drv._transact(b"FOO:BAR 1", False)
    drv._transact(b"SOUR:VOLT 99", False)
    errs = drv.errors()
    assert [c for c, _ in errs] == [-113, -222]
    assert drv.errors() == []
    for _ in range(40):
        drv._transact(b"BOGUS", False)
    errs = drv.errors()
    assert len(errs) == 32 and errs[-1][0] == -350 and all(c == -113 for c, _ in errs[:-1])
    drv._transact(b"BOGUS", False)
    drv.reset()  # *CLS clears
    assert drv.errors() == []


def test_bad_block_and_type_errors(awg_pair):
    drv, sim = awg_pair
    drv._transact(b"SOUR:DATA:ARB #5123", False)   # announces more bytes than present
    drv._transact(b"OUTP MAYBE", False)
    drv._transact(b"SOUR:DATA:ARB #13abc", False)  # odd byte count
    assert [c for c, _ in drv.errors()] == [-160, -104, -160]


def test_invalid_arguments_refused_before_sending(awg_pair):
    drv, sim = awg_pair
    with pytest.raises(InvalidArgument):
        drv.upload_waveform(np.array([0.0, 2.0]))
    with pytest.raises(InvalidArgument):
        drv.set_amplitude(-1.0)
    with pytest.raises(InvalidArgument):
        drv.upload_waveform(np.ones(10), units="volts")
    assert sim.codes.size == 2  # nothing uploaded


def test_timeout_is_retried_then_succeeds(awg_pair):
    drv, sim = awg_pair
    sim.inject_fault("timeout", "bulk_in", count=2)
    assert drv.identify().model == "AWG-16"


def test_persistent_timeout_becomes_device_timeout(awg_pair):
    drv, sim = awg_pair
    sim.inject_fault("timeout", "bulk_out", count=10)
    with pytest.raises(DeviceTimeout) as ei:
        drv.set_sample_rate(1e8)
    assert ei.value.device == "awg" and "SOUR:FREQ:SAMP" in ei.value.command


def test_unanswered_query_times_out(awg_pair):
    drv, sim = awg_pair
    with pytest.raises(DeviceTimeout, match="awg"):
        drv.query(b"NOPE?")


def test_stall_and_disconnect_are_typed(awg_pair):
    drv, sim = awg_pair
    sim.inject_fault("stall", "bulk_out")
    with pytest.raises(DeviceStall, match="awg"):
        drv.output(True)
    assert drv.identify().model == "AWG-16"  # usable after the halt was cleared
    sim.inject_fault("disconnect")
    with pytest.raises(DeviceDisconnected) as ei:
        drv.output(True)
    assert ei.value.device == "awg" and ei.value.command == "OUTP ON"
