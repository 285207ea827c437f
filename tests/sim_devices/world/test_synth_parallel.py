"""A digitizer read synthesized in parts on threads (sim_devices.world.synth_parallel): each part is
exactly the read of its segments alone (its own generator, seeded as the bench seeds a read; the white
noise's stream shifted to its first segment), the parts join in order, the records do not depend on
the cut, and the noise keeps its level (eq. 2-13: sigma = ASD sqrt(fs / 2))."""

import numpy as np
import pytest

from lidard.config import load_laser
from sim_devices.world import synth_parallel as sp
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.gauss import NoiseStream, stream_key
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
    assert sp.read_parts(n_seg, n) == 4                        # 15 parts' worth of samples: 4 (MAX_PARTS)
    seg = np.repeat(np.arange(n_seg), 2)[::3]                  # some segments empty, some with two hits
    hits = HitBatch.from_targets(seg, 0.3 + 0.02 * np.arange(seg.size), 0.05,
                                 radial_velocity_m_s=0.1 * np.sin(np.arange(seg.size)))
    t0 = np.arange(n_seg) * 2 * RAMP_S
    noise = NoiseStream(stream_key(7, 1), 1000)
    kw = dict(effects=Effects(noise_asd_v_per_rthz=2e-6, linewidth_hz=0.0))
    whole = sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=workers, noise=noise, **kw)
    bounds = np.linspace(0, n_seg, sp.read_parts(n_seg, n) + 1).astype(int)
    for a, b in zip(bounds[:-1], bounds[1:]):
        part = synthesize(traj, adc, t0[a:b], sp._part_hits(hits, a, b), rng=_rng_for(a), noise=noise.shifted(a), **kw)
        assert np.array_equal(whole.beat[a:b], part.beat)
        assert np.array_equal(whole.overrange[a:b], part.overrange)
    assert whole.beat.shape == (n_seg, n)


@pytest.mark.parametrize("iq", [False, True])
def test_the_records_of_a_read_do_not_depend_on_its_cut(traj, monkeypatch, iq):
    """The white noise of a record is a function of its trigger index: a read in 1, 2 or 4 parts (on
    threads) gives the same bytes; the noise is there at its level, and another stream key draws
    other noise of the same level."""
    fs, n, n_seg = 10e6, 1601, 48
    adc = AdcSpec(fs, n, bits=16, input_range_v=1.0, quantize=True, iq=iq)
    monkeypatch.setattr(sp, "MIN_PART_SAMPLES", 4 * n)
    seg = np.repeat(np.arange(n_seg), 2)[::3]
    hits = HitBatch.from_targets(seg, 0.3 + 0.02 * np.arange(seg.size), 0.05)
    t0 = np.arange(n_seg) * 2 * RAMP_S
    sigma_v = 2e-6 * np.sqrt(fs / 2)
    kw = dict(effects=Effects(noise_asd_v_per_rthz=2e-6))
    noise = NoiseStream(stream_key(7, 1), 5000)
    reads = {w: sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=w, noise=noise, **kw) for w in (1, 2, 4)}
    for w in (2, 4):
        assert np.array_equal(reads[w].beat, reads[1].beat)
        assert np.array_equal(reads[w].overrange, reads[1].overrange)
        if iq:
            assert np.array_equal(reads[w].beat_q, reads[1].beat_q)
    clean = synthesize(traj, adc, t0, hits)
    noise_v = (reads[1].beat.astype(float) - clean.beat.astype(float)) * adc.lsb_v
    assert np.std(noise_v) == pytest.approx(sigma_v, rel=0.03)
    other = sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=2, noise=NoiseStream(stream_key(7, 2), 5000), **kw)
    diff_v = (other.beat.astype(float) - reads[1].beat.astype(float)) * adc.lsb_v
    assert np.std(diff_v) == pytest.approx(np.sqrt(2) * sigma_v, rel=0.03)
    if iq:     # the I and Q channels draw their own noise: uncorrelated
        noise_q = (reads[1].beat_q.astype(float) - clean.beat_q.astype(float)) * adc.lsb_v
        assert abs(np.corrcoef(noise_v.ravel(), noise_q.ravel())[0, 1]) < 5 / np.sqrt(noise_v.size)


def test_a_small_read_stays_on_the_calling_thread_unchanged(traj):
    adc = AdcSpec(10e6, 1600, bits=16, input_range_v=1.0, quantize=True)
    t0 = np.arange(8) * 2 * RAMP_S
    hits = HitBatch.from_targets(np.arange(8), np.full(8, 0.5), 0.05)
    a = sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=4, effects=Effects(noise_asd_v_per_rthz=2e-6))
    b = synthesize(traj, adc, t0, hits, rng=_rng_for(0), effects=Effects(noise_asd_v_per_rthz=2e-6))
    assert np.array_equal(a.beat, b.beat)


def test_the_cut_is_a_function_of_the_read_alone():
    """Parts: a power of two, at most MAX_PARTS and the segment count, each at least MIN_PART_SAMPLES;
    more samples never give fewer parts."""
    m = sp.MIN_PART_SAMPLES
    assert sp.read_parts(1, 10 * m) == 1 and sp.read_parts(100, m // 100) == 1     # one segment / too small
    assert [sp.read_parts(64, k * m // 64) for k in (1, 2, 3, 4, 7, 8, 64)] == [1, 2, 2, 4, 4, 4, 4]
    assert sp.read_parts(3, 100 * m) == 2                                          # 3 segments: 2 parts
    for n_seg in (1, 2, 5, 17, 200, 4096):
        for n in (64, 1190, 9520, 32000):
            k = sp.read_parts(n_seg, n)
            assert k & (k - 1) == 0 and 1 <= k <= min(sp.MAX_PARTS, n_seg)
            assert k == 1 or n_seg // k * n >= m // 2        # parts of about MIN_PART_SAMPLES or more


def test_a_read_with_phase_noise_gives_the_same_records_on_any_number_of_threads(traj, monkeypatch):
    """The phase noise a part draws depends on where the read is cut: the cut follows the read, not the
    cores, so a bench seed gives the same bytes on 1, 2, 3 or 4 threads (before, the cut was one part per
    thread and the records changed with the machine)."""
    fs, n, n_seg = 10e6, 1600, 40
    adc = AdcSpec(fs, n, bits=16, input_range_v=1.0, quantize=True)
    monkeypatch.setattr(sp, "MIN_PART_SAMPLES", 4 * n)
    hits = HitBatch.from_targets(np.arange(n_seg), np.full(n_seg, 3.0), 0.05)   # 3 m: phase noise shows
    t0 = np.arange(n_seg) * 2 * RAMP_S
    kw = dict(effects=Effects(noise_asd_v_per_rthz=2e-7, linewidth_hz=2e6))
    reads = {w: sp.synthesize_read(traj, adc, t0, hits, _rng_for, workers=w, **kw).beat for w in (1, 2, 3, 4)}
    for w in (2, 3, 4):
        assert np.array_equal(reads[w], reads[1])
    # the phase noise is in the records: another cut (one part) draws other phase noise
    whole = synthesize(traj, adc, t0, hits, rng=_rng_for(0), **kw).beat
    assert not np.array_equal(whole, reads[1])
