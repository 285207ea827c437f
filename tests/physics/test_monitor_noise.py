"""The monitor-MZI channel's own noise (issue 15 item 4): shot + RIN of its photodiode and the ADC's
quantization of its channel, and that this noise reaches the ILC's measurement (§2.2)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lidard.config import CONFIG_DIR, load_config, load_laser
from lidard.dsp.linearize.ilc import IlcSettings, linearize
from lidard.dsp.linearize.ilc import ChirpGeometry
from lidard.physics.budget import monitor_noise_asd
from sim_devices.bench.bench import Bench
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, MonitorMzi, synthesize, trajectory

Q = 1.602176634e-19


def test_monitor_noise_formula_by_hand():
    # 0.3 V fringe amplitude from 100 uW at 0.95 A/W: G = 0.3 / 95 uA = 3158 V/A;
    # shot = G sqrt(2 q 95 uA) = 3158 * 5.517e-12 = 1.742e-8 V/rtHz; RIN -150 dB: 0.3 * 3.162e-8
    c = monitor_noise_asd(0.3, 100e-6, 0.95, -150.0)
    assert c["shot"] == pytest.approx(0.3 / 95e-6 * math.sqrt(2 * Q * 95e-6), rel=1e-9)
    assert c["shot"] == pytest.approx(1.742e-8, rel=1e-3)
    assert c["rin"] == pytest.approx(9.487e-9, rel=1e-3)
    assert c["total"] == pytest.approx(math.hypot(1.742e-8, 9.487e-9), rel=1e-3)
    # shot noise relative to the fringe falls as 1/sqrt(P): 4x the power, half the shot ASD
    assert monitor_noise_asd(0.3, 400e-6, 0.95, -150.0)["shot"] == pytest.approx(c["shot"] / 2)
    with pytest.raises(ValueError, match="power_w"):
        monitor_noise_asd(0.3, 0.0, 0.95, -150.0)


def test_bench_monitor_channel_carries_shot_rin_and_core_quantization():
    cfg = load_config(CONFIG_DIR / "sim.toml")
    bench = Bench(cfg)
    shot_rin = monitor_noise_asd(cfg.monitor.amplitude_v, cfg.monitor.power_w,
                                 cfg.detector.responsivity_a_per_w,
                                 bench.laser_preset.rin_db_per_hz)["total"]
    lsb = cfg.adc.input_range_v / 2**cfg.adc.bits
    q_core = math.sqrt(lsb**2 / 12 / (cfg.adc.max_sample_rate_hz / 2))
    from sim_devices.digitizer.device import CaptureConfig

    def capture(resolution_bits: int) -> CaptureConfig:   # the resolution the host configured
        return CaptureConfig(10e6, 1600, ("beat", "mzi"), 16, cfg.adc.input_range_v, resolution_bits)
    assert bench.synthesizer.monitor_asd(capture(16)) == pytest.approx(math.hypot(shot_rin, q_core), rel=1e-9)
    assert bench.synthesizer.monitor_asd(capture(cfg.adc.bits)) == pytest.approx(shot_rin, rel=1e-9)  # record = core


RAMP_S, EXC_HZ, FS, TAU_M = 80e-6, 8.6e9, 100e6, 200e-9


def _ilc_floor(noise_asd: float, seed: int = 5) -> float:
    """ILC's first measurement of an ideal (zero-linewidth) laser through a monitor whose only
    noise is the additive white noise ``noise_asd`` (16-bit record: its own LSB is negligible)."""
    laser = DfbLaser(load_laser("dfb_default"))
    rng = np.random.default_rng(seed)
    n = int(2 * RAMP_S * FS)
    adc = AdcSpec(sample_rate_hz=FS, n_samples=n, bits=16, input_range_v=1.0)

    def measure(drive, n_avg):
        out = synthesize(trajectory(laser, drive, FS), adc, np.zeros(n_avg), None, effects=Effects(linewidth_hz=0.0),
                         rng=rng, mzi=MonitorMzi(TAU_M, 0.3, noise_asd))
        return out.mzi.astype(np.float64) * adc.lsb_v

    u0 = triangle_drive(EXC_HZ, RAMP_S, FS, laser.static_tuning_hz_per_v)
    res = linearize(measure, u0, ChirpGeometry(fs_drive_hz=FS, fs_adc_hz=FS, ramp_s=RAMP_S, excursion_hz=EXC_HZ, mzi_delay_s=TAU_M), IlcSettings(averages=8, max_iter=0))
    return float(res.iterations[0].noise_floor_hz)


def test_monitor_noise_reaches_the_ilc_noise_floor_linearly():
    # Additive noise sigma_v on a fringe of amplitude A is a phase error sigma_v / A, i.e. a
    # frequency error proportional to sigma_v: the ILC's measured floor scales with the ASD.
    base = 2e-7  # ~ the 8-bit core's quantization ASD at 1 GS/s, well above the 16-bit LSB
    f1, f4 = _ilc_floor(base), _ilc_floor(4 * base)
    assert f4 / f1 == pytest.approx(4.0, rel=0.25)
    assert _ilc_floor(0.0) < 0.2 * f1   # without monitor noise the floor is far lower
