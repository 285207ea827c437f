"""The digitizer's decimation filter (lidard.physics.decimation) and its action on synthesized beats
(sim_devices.world.antialias): the response's shape, and a tone beyond fs/2 attenuated at its TRUE
beat frequency 2 gamma d / c (§2.1.1) before it folds."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import load_laser
from lidard.physics.constants import C_M_PER_S
from lidard.physics.decimation import DecimationError, DecimationFilter
from sim_devices.digitizer.device import decimation_filter
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, synthesize, trajectory

RAMP_S, EXC_HZ = 80e-6, 8.6e9
GAMMA = EXC_HZ / RAMP_S
FS = 5e6


def test_response_pass_transition_and_stop_band():
    f = DecimationFilter(80.0)
    assert np.allclose(f.gain([0.0, 1e6, 0.4 * FS], FS), 1.0)
    assert np.allclose(f.gain([0.6 * FS, 0.9 * FS, 7.3 * FS], FS), 1e-4)
    # power complementary about fs/2: the folded noise stays white
    x = np.linspace(0.4, 0.6, 41) * FS
    assert np.allclose(f.gain(x, FS) ** 2 + f.gain(FS - x, FS) ** 2, 1.0, atol=1e-7)
    assert f.gain(0.5 * FS, FS) == pytest.approx(np.sqrt(0.5))
    assert f.alias_free_hz(FS) == pytest.approx(0.4 * FS)
    assert f.alias_ceiling_v(1.0) == pytest.approx(0.5e-4)


@pytest.mark.parametrize("bad", [0.0, -3.0, float("nan")])
def test_bad_stopband_is_named(bad):
    with pytest.raises(DecimationError, match="stopband_db"):
        DecimationFilter(bad)


def test_no_filter_at_the_core_rate():
    assert decimation_filter(1e9, 1e9, 80.0) is None
    assert decimation_filter(5e6, 1e9, 80.0) is not None


@pytest.fixture(scope="module")
def traj():
    laser = DfbLaser(load_laser("ideal"))
    return trajectory(laser, triangle_drive(EXC_HZ, RAMP_S, 100e6, laser.static_tuning_hz_per_v), 100e6)


@pytest.mark.parametrize("d_m", [1.0, 2.3, 3.8, 5.0, 10.0])
def test_tones_are_filtered_at_their_true_beat_then_fold(traj, d_m):
    n = int(round(RAMP_S * FS))
    adc = AdcSpec(FS, n, bits=16, input_range_v=2.0, quantize=False)
    hits = HitBatch.from_targets([0], [d_m], 0.5)
    filt = decimation_filter(FS, 1e9, 60.0)
    beat = synthesize(traj, adc, np.zeros(1), hits, effects=Effects(beat_filter=filt)).beat[0]
    f_true = 2 * GAMMA * d_m / C_M_PER_S
    expect = 0.5 * float(DecimationFilter(60.0).gain(f_true, FS))
    # the up ramp's middle half, away from the turning point: amplitude of the folded tone
    seg = beat[n // 8: 3 * n // 8]
    amp = np.sqrt(2.0 * np.mean(seg ** 2))
    assert amp == pytest.approx(expect, rel=0.02)
    f_alias = abs(f_true - FS * round(f_true / FS))
    spec = np.abs(np.fft.rfft(beat[: n // 2] * np.hanning(n // 2)))
    f_peak = np.fft.rfftfreq(n // 2, 1 / FS)[np.argmax(spec)]
    assert abs(f_peak - f_alias) <= 2 * FS / (n // 2)


def test_the_core_clips_before_the_filter():
    from sim_devices.bench.bench import core_overrange
    hits = HitBatch(seg=np.array([0, 1, 2, 2]), tau_s=np.full(4, 1e-7), amplitude_v=np.array([0.6, 0.4, 0.3, 0.3]))
    # +-0.5 V full scale: 0.6 V clips, 0.4 V does not, two returns of 0.3 V can (their peaks align)
    assert list(core_overrange(hits, 4, 1.0)) == [True, False, True, False]
