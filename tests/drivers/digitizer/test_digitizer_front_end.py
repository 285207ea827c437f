"""The digitizer's resolution and anti-alias bandwidth act on the record (driver <-> SimDigitizer).

Expectations come from the definitions, not from the simulator: a b-bit quantizer in the 16-bit
format has steps of 2**(16 - b) codes and an error of at most half a step; the anti-alias filter's
power response is the formula of docs/protocols/digitizer.md ("Bandwidth limit"):
|G(f)| = 1 / (1 + (sqrt(2) - 1) * (tan(pi f / fs) / tan(pi fc / fs))**8) in amplitude.
"""

import math

import numpy as np
import pytest
import usb.core

from drivers.digitizer import protocol as p
from drivers.digitizer.driver import DigitizerDriver, DigitizerError
from drivers.usbtmc import InvalidArgument
from sim_devices.clock import VirtualClock
from sim_devices.digitizer.device import CapturedSegments, SimDigitizer
from sim_devices.usb.backend import SimUsbBackend

FS = 100e6
N = 4000  # 40 us: every tone below has a whole number of cycles


class Tones:
    """Channel 0 of every segment: sum of (freq_hz, amplitude_codes) tones plus optional white noise."""

    def __init__(self, tones, noise_codes=0.0):
        self.tones, self.noise = tones, noise_codes

    def analog(self, first, count, cfg):
        t = np.arange(cfg.record_length) / cfg.sample_rate_hz
        x = sum(a * np.sin(2 * np.pi * f * t) for f, a in self.tones) * np.ones((count, 1))
        if self.noise:
            x = x + np.random.default_rng(first).normal(0.0, self.noise, (count, cfg.record_length))
        return x

    def capture(self, first, count, cfg):
        codes = np.rint(self.analog(first, count, cfg)).astype(np.int16)[:, None, :]
        return CapturedSegments(np.arange(first, first + count) * 1e-4, codes,
                                np.zeros((count, 1), dtype=bool))


def _record(source, *, resolution_bits=None, bandwidth_hz=None, segments=4):
    sim = SimDigitizer(VirtualClock(), source)
    dev = usb.core.find(idVendor=p.DIGITIZER_VID, idProduct=p.DIGITIZER_PID, backend=SimUsbBackend([sim]))
    drv = DigitizerDriver(dev, timeout_ms=200, retries=0)
    cfg = drv.configure(channels=("beat",), sample_rate_hz=FS, record_length=N, segments=segments, bits=16,
                        input_range_v=1.0, resolution_bits=resolution_bits, bandwidth_hz=bandwidth_hz)
    drv.arm()
    _, s = drv.read_segments(0, segments, cfg)
    return cfg, s[:, 0, :].astype(np.float64), drv, sim


def _amplitude(x, f_hz):
    """Least-squares amplitude of a tone at f_hz in the middle half of each record (no edges)."""
    t = np.arange(N) / FS
    mid = slice(N // 4, 3 * N // 4)
    basis = np.stack([np.sin(2 * np.pi * f_hz * t[mid]), np.cos(2 * np.pi * f_hz * t[mid])], axis=1)
    coef, *_ = np.linalg.lstsq(basis, x[:, mid].T, rcond=None)
    return float(np.mean(np.hypot(coef[0], coef[1])))


def _gain(f_hz, fc_hz):
    """Amplitude response of the documented anti-alias filter."""
    r = np.tan(np.pi * np.asarray(f_hz) / FS) / math.tan(math.pi * fc_hz / FS)
    return 1.0 / (1.0 + (math.sqrt(2.0) - 1.0) * r**8)


def test_a_12_bit_record_has_12_bit_quantization_steps():
    src = Tones([(1e6, 12_000.0), (3.25e6, 5_000.0)])
    cfg, x, _, _ = _record(src, resolution_bits=12)
    assert cfg.resolution_bits == 12 and cfg.bits == 16
    step = 2 ** (16 - 12)
    assert np.all(x % step == 0)
    assert np.diff(np.unique(x)).min() == step            # adjacent levels one 12-bit LSB apart
    analog = src.analog(0, 4, cfg)
    assert np.max(np.abs(x - analog)) <= step / 2 + 0.5   # rounding to the step (+ the source's own)
    # at the full 16-bit resolution the record is the source, untouched
    _, x16, _, _ = _record(src)
    assert np.array_equal(x16, np.rint(analog))


def test_a_tone_above_the_bandwidth_is_attenuated_by_the_documented_amount():
    fc = 5e6
    f_stop, f_pass = 10e6, 1e6
    src = Tones([(f_pass, 1_000.0), (f_stop, 20_000.0)])
    cfg, x, _, _ = _record(src, bandwidth_hz=fc)
    assert cfg.bandwidth_hz == 5_000_000
    want_db = 20 * math.log10(_gain(f_stop, fc))
    got_db = 20 * math.log10(_amplitude(x, f_stop) / 20_000.0)
    assert want_db < -40                                  # a real stop band, not a slope
    assert got_db == pytest.approx(want_db, abs=0.3)
    assert 20 * math.log10(_amplitude(x, f_pass) / 1_000.0) == pytest.approx(0.0, abs=0.02)
    # at the corner itself: -3.01 dB
    _, xc, _, _ = _record(Tones([(fc, 10_000.0)]), bandwidth_hz=fc)
    assert 20 * math.log10(_amplitude(xc, fc) / 10_000.0) == pytest.approx(-10 * math.log10(2), abs=0.02)


def test_the_band_limit_filters_the_noise_too():
    fc, sigma = 5e6, 1_000.0
    _, x, _, _ = _record(Tones([], noise_codes=sigma), bandwidth_hz=fc, segments=8)
    f = np.linspace(0.0, FS / 2 * (1 - 1e-9), 20_001)
    enbw_fraction = np.trapezoid(_gain(f, fc) ** 2, f) / (FS / 2)   # white noise: power follows |G|^2
    assert np.var(x[:, 200:-200]) / sigma**2 == pytest.approx(enbw_fraction, rel=0.1)
    assert enbw_fraction == pytest.approx(fc / (FS / 2), rel=0.05)  # a steep filter: ENBW ~ fc


def test_bad_resolution_and_bandwidth_are_refused():
    _, _, drv, sim = _record(Tones([(1e6, 100.0)]), resolution_bits=12, segments=1)
    drv.abort()
    with pytest.raises(InvalidArgument, match="resolution"):
        drv.set_resolution(6)
    with pytest.raises(InvalidArgument, match="bandwidth"):
        drv.set_bandwidth(-1.0)
    drv.set_format(8)
    assert sim.config.resolution_bits == 8              # a new format starts at its own resolution
    with pytest.raises(DigitizerError) as ei:           # 12 bits do not fit 8-bit samples: STALL
        drv.set_resolution(12)
    assert ei.value.command == "SET_RESOLUTION" and ei.value.device == "digitizer"
