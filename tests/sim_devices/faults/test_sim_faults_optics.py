"""Optical faults: a stuck MEMS switch (light from the wrong pixels or none; the tap monitor sees 2x
or 0) and digitizer overrange (the beat clips at full scale, the segment header flags it)."""


import numpy as np
import pytest
import usb.core

from drivers.digitizer import protocol as dig_p
from drivers.digitizer.driver import DigitizerDriver
from sim_devices.digitizer.device import CaptureConfig
from tests.helpers.sim_bench import chirp_on, fpsa, power_up, restart, run_pattern

TAP = CaptureConfig(10e6, 200, ("tap",), 16, 1.0)


def _tap_v(bench, n: int) -> np.ndarray:
    cap = bench.capture(0, n, TAP)
    return cap.codes[:, 0].mean(axis=1) * (TAP.input_range_v / 2**TAP.bits)


def _digitizer(bench) -> DigitizerDriver:
    dev = usb.core.find(idVendor=dig_p.DIGITIZER_VID, idProduct=dig_p.DIGITIZER_PID,
                        backend=bench.usb_backend)
    return DigitizerDriver(dev)


def test_tap_reads_one_beam_per_healthy_pixel_and_scales_with_the_link(bench):
    power_up(bench)
    fp = fpsa(bench)
    fp.reset()
    run_pattern(fp, [[0, 0], [1, 5], [2, 9]])
    level = _tap_v(bench, 3)
    # V = G_tap * R * tap fraction * P_tx, P_tx = 1 mW out of the FPSA in sim.toml
    expect = (bench.tap.gain_v_per_a * bench.cfg.detector.responsivity_a_per_w * bench.tap.fraction
              * bench.cfg.link.tx_power_w)
    assert bench.tap_volts_per_beam() == pytest.approx(expect)
    assert np.allclose(level, expect, rtol=0.02)
    fp.close()


def test_stuck_on_row_doubles_and_emits_from_the_wrong_pixel(bench):
    power_up(bench)
    fp = fpsa(bench)
    fp.reset()
    pixels = [[0, 3], [1, 7], [2, 11], [8, 20]]
    run_pattern(fp, pixels)
    bench.inject_fault("stuck_switch", line="row", index=5, state="on")
    restart(fp)
    one = bench.tap_volts_per_beam()
    assert np.allclose(_tap_v(bench, 4), 2 * one, rtol=0.03)
    # the world sees light leave through (5, col) as well as the commanded (row, col)
    trig = bench.fpga.triggers(0, 4, TAP.record_length / TAP.sample_rate_hz)
    for i, (r, c) in enumerate(pixels):
        rows, cols, trans = trig.beams_of(i)
        lit = {(int(a), int(b)) for a, b, t in zip(rows, cols, trans) if t > 0.5}
        assert lit == {(r, c), (5, c)}
    # the drive is untouched: the HV583 never raised row 5
    rows_high, _ = bench.fpga.lines_high()
    assert not rows_high[5]
    bench.clear_faults("stuck_switch")
    restart(fp)
    assert np.allclose(_tap_v(bench, 4), one, rtol=0.03)
    fp.close()


def test_stuck_off_column_darkens_its_pixels_only(bench):
    power_up(bench)
    fp = fpsa(bench)
    fp.reset()
    run_pattern(fp, [[0, 3], [1, 7], [2, 7], [4, 9]])
    bench.inject_fault("stuck_switch", line="col", index=7, state="off")
    restart(fp)
    one = bench.tap_volts_per_beam()
    level = _tap_v(bench, 4)
    assert np.allclose(level[[0, 3]], one, rtol=0.03)
    assert np.all(np.abs(level[[1, 2]]) < 0.02 * one)
    bench.clear_faults()
    restart(fp)
    assert np.allclose(_tap_v(bench, 4), one, rtol=0.03)
    fp.close()


def test_self_test_sweep_through_the_digitizer_finds_the_stuck_lines(bench):
    """What a host self-test does: one pixel per row and per column, the tap per trigger."""
    power_up(bench)
    fp = fpsa(bench)
    fp.reset()
    rows = [r for r in range(16) if r % 4 != 3]
    pixels = [[r, (5 * r) % 16] for r in rows]
    run_pattern(fp, pixels)
    bench.inject_fault("stuck_switch", line="row", index=9, state="off")
    bench.inject_fault("stuck_switch", line="col", index=2, state="on")
    restart(fp)
    dig = _digitizer(bench)
    cfg = dig.configure(channels=("beat", "tap"), sample_rate_hz=10e6, record_length=200,
                        segments=len(pixels), bits=16, input_range_v=1.0)
    dig.arm()
    _, samples = dig.read_segments(0, len(pixels), cfg)
    level = samples[:, 1].mean(axis=1) / 2**16 / bench.tap_volts_per_beam()
    beams = np.rint(level).astype(int)
    expect = [0 if r == 9 else (1 if c == 2 else 2) for r, c in pixels]
    assert beams.tolist() == expect
    fp.close()


def test_digitizer_overrange_clips_the_beat_and_sets_the_header_flag(bench):
    power_up(bench)
    chirp_on(bench)
    fp = fpsa(bench)
    fp.reset()
    pixels = [[44, 50], [45, 52], [46, 60], [48, 64]]      # the CAL letters at 0.9 m
    assert np.all(bench.ground_truth(np.array(pixels)[:, 0], np.array(pixels)[:, 1]) < 1.0)
    run_pattern(fp, pixels)
    dig = _digitizer(bench)

    def acquire():
        cfg = dig.configure(channels=("beat",), sample_rate_hz=5e6, record_length=400,
                            segments=len(pixels), bits=16, input_range_v=1.0)
        dig.arm()
        headers, samples = dig.read_segments(0, len(pixels), cfg)
        return headers, samples.astype(np.int32), dig.status()

    headers, samples, _ = acquire()
    normal_peak = np.abs(samples).max(axis=2)
    assert all(h.overrange == 0 for h in headers)
    assert np.all(normal_peak > 20) and np.all(normal_peak < 1000)   # a ~1 mV beat, far from 0.5 V
    bench.inject_fault("digitizer_overrange", gain=1000)
    headers, samples, status = acquire()
    assert all(h.overrange == 0b1 for h in headers)
    assert status.overrange_count == len(pixels)
    assert samples.max() == 32767 and samples.min() == -32768     # clipped at full scale
    clipped = np.mean((samples == 32767) | (samples == -32768))
    assert clipped > 0.2
    bench.clear_faults("digitizer_overrange")
    headers, samples, _ = acquire()
    assert all(h.overrange == 0 for h in headers)
    assert np.array_equal(np.abs(samples).max(axis=2), normal_peak)  # same seeded noise, same bytes
    fp.close()
