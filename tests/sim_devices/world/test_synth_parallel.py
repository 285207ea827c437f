"""A digitizer read synthesized in parts on threads (sim_devices.world.synth_parallel): each part is
exactly the read of its segments alone (its own generator, seeded as the bench seeds a read), the
parts join in order, and the noise keeps its level (eq. 2-13: sigma = ASD sqrt(fs / 2))."""

import numpy as np
import pytest

from lidard.config import load_laser
from sim_devices.world import synth_parallel as sp
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, Effects, HitBatch, synthesize, trajectory

RAMP_S, EXC_HZ = 80e-6, 8.6e9


@pytest.fixture(scope="module")
def traj():
    laser = DfbLaser(load_laser("ideal"))
    return trajectory(laser, triangle_drive(EXC_HZ, RAMP_S, 100e6, laser.static_tuning_hz_per_v), 100e6)


def _rng_for(s):
    return np.random.default_rng([7, 1, 1000 + s])


@pytest.mark.parametrize("workers", [2, 3])
def test_a_read_in_parts_is_the_reads_of_its_parts_joined(traj, monkeypatch, workers):
    fs, n, n_seg = 10e6, 1600, 60
    adc = AdcSpec(fs, n, bits=16, input_range_v=1.0, quantize=True)
    monkeypatch.setattr(sp, "MIN_PART_SAMPLES", 4 * n)
    seg = np.repeat(np.arange(n_seg), 2)[::3]                  # some segments empty, some with two hits
    hits = HitBatch.from_targets(seg, 0.3 + 0.02 * np.arange(seg.size), 0.05,
                                 radial_velocity_m_s=0.1 * np.sin(np.arange(seg.size)))
    t0 = np.arange(n_seg) * 2 * RAMP_S
    kw = dict(effects=Effects(noise_asd_v_per_rthz=2e-6, linewidth_hz=0.0))
    whole = sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=workers, **kw)
    bounds = np.linspace(0, n_seg, workers + 1).astype(int)
    for a, b in zip(bounds[:-1], bounds[1:]):
        part = synthesize(traj, adc, t0[a:b], sp._part_hits(hits, a, b), rng=_rng_for(a), **kw)
        assert np.array_equal(whole.beat[a:b], part.beat)
        assert np.array_equal(whole.overrange[a:b], part.overrange)
    one = sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=1, **kw)
    assert whole.beat.shape == one.beat.shape == (n_seg, n)
    # a different cut of the noise stream, the same signal: records differ by noise only, of the right level
    sigma_v = 2e-6 * np.sqrt(fs / 2)
    diff_v = (whole.beat.astype(float) - one.beat.astype(float)) * adc.lsb_v
    assert np.std(diff_v) == pytest.approx(np.sqrt(2) * sigma_v, rel=0.05)


def test_a_small_read_stays_on_the_calling_thread_unchanged(traj):
    adc = AdcSpec(10e6, 1600, bits=16, input_range_v=1.0, quantize=True)
    t0 = np.arange(8) * 2 * RAMP_S
    hits = HitBatch.from_targets(np.arange(8), np.full(8, 0.5), 0.05)
    a = sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=4, effects=Effects(noise_asd_v_per_rthz=2e-6))
    b = synthesize(traj, adc, t0, hits, rng=_rng_for(0), effects=Effects(noise_asd_v_per_rthz=2e-6))
    assert np.array_equal(a.beat, b.beat)
