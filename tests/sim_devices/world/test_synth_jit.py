"""The compiled static beat phase (sim_devices.world.synth_jit) against the numpy path it stands in for
(synth_grid._fill): the same float64 operations in the same order, so the same values bit for bit, on
the bench's own chirp tables at the sample-rate ratios a scan uses; the quantizer with the records' noise
drawn in its pass against gauss' numpy generator and the numpy quantizer passes."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sim_devices.world import synth_grid, synth_jit
from sim_devices.world.gauss import NoiseStream, stream_key

pytest.importorskip("numba")


def _tables(rng, length):
    # a chirp phase in cycles: large, smooth c0 and its per-interval slopes, as ChirpTrajectory tiles them
    c1 = 1e3 + 50.0 * np.sin(np.arange(length) / 97.0) + rng.normal(0, 1e-3, length)
    c2 = rng.normal(0, 1e-2, length)
    c0 = np.concatenate([[0.0], np.cumsum(c1[:-1] + c2[:-1])])
    return c0, c1, c2


@pytest.mark.parametrize("ratio", [20.0, 2.5, 100.0 / 15.0, 1.25])
@pytest.mark.parametrize("spread", [900.0, 3.0])
def test_kernel_gives_the_numpy_fill_bit_for_bit(ratio, spread):
    rng = np.random.default_rng(7)
    pq = synth_grid.rational_ratio(ratio)
    assert pq is not None
    n = 1190
    c0, c1, c2 = _tables(rng, int(n * ratio) + 4000)
    # delays of a scene's hits, AWG samples: spread over the range gate, or a few samples apart (a
    # surface at one distance: many hits share their integer offset from the grid)
    d_awg = rng.uniform(0.0, spread, 37) + 1.0
    d_awg[:5] = np.rint(d_awg[:5])                 # whole-sample delays too
    const = rng.uniform(-5e3, 5e3, d_awg.size)
    b_start = 1000.0 + 0.375
    want = np.empty((d_awg.size, n))
    synth_grid._fill(c0, c1, c2, b_start, ratio, pq, n, d_awg, -const[:, None], want)
    kernel = synth_jit._compiled()
    got = np.empty_like(want)
    kernel(c0, c1, c2, b_start, ratio, pq[0], pq[1], n, d_awg, -const, got)
    assert np.array_equal(got.view(np.int64), want.view(np.int64))


def test_kernel_waits_until_loading_numba_pays(monkeypatch):
    monkeypatch.setattr(synth_jit, "_asked", [0])
    monkeypatch.setattr(synth_jit, "_numba_loaded", lambda: False)     # a process that has not loaded it
    synth_jit._compiled.cache_clear()
    try:
        assert synth_jit.static_fill(1000) is None                          # a small scan: numpy
        assert synth_jit.static_fill(synth_jit.LOAD_AFTER_SAMPLES) is not None   # past the break-even
        monkeypatch.setenv("LIDARD_DSP_JIT", "0")
        assert synth_jit.static_fill(1) is None
    finally:
        synth_jit._compiled.cache_clear()


@pytest.mark.parametrize("bits", [16, 12, 8])
@pytest.mark.parametrize("mzi_asd", [0.0, 2e-6])
def test_quantizer_kernel_gives_the_numpy_passes_codes_and_flags(monkeypatch, bits, mzi_asd):
    from sim_devices.world import synth_chunk
    from sim_devices.world.synth_types import AdcSpec
    adc = AdcSpec(sample_rate_hz=5e6, n_samples=1190, bits=bits, input_range_v=1.0)
    nc, channels = 24, ["beat", "mzi"]
    rng = np.random.default_rng(3)
    beat = (rng.normal(0, 0.05, (nc, adc.n_samples)) * np.linspace(0.1, 12.0, nc)[:, None]).astype(np.float32)
    beat[:, 7] = 0.5 * adc.lsb_v + np.float32(0.25) * adc.lsb_v * np.arange(nc)   # ties and near-ties of rint
    std = np.concatenate([np.full(12, 3e-3), np.full(12, 4e-2)])[:nc]      # two noise levels: the per-row scale
    std[5] = 0.0                                                            # a dark record: no noise

    def run(kernels):
        monkeypatch.setattr(synth_jit, "quantize_rows",
                            lambda samples, noisy=False: None if kernels is None else kernels[1] if noisy else kernels[0])
        acc = {"beat": beat.copy(), "mzi": np.zeros((nc, adc.n_samples), np.float32)}
        outs = {c: np.empty((nc, adc.n_samples), np.int16) for c in channels}
        over = np.zeros((nc, 2), bool)
        # the chunk run's fields digitize_chunk reads (the rest of a ChunkRun is the beat's, not used here)
        run_ = SimpleNamespace(adc=adc, dc_v=0.0, noise_std=std, mzi_noise_asd_v_per_rthz=mzi_asd,
                               noise=NoiseStream(stream_key(11), 40))
        synth_chunk.digitize_chunk(run_, acc, channels, 0, nc, outs, over, None)
        return outs, over

    want_codes, want_over = run(None)
    got_codes, got_over = run(synth_jit._quantizer())
    assert want_over[:, 0].any() and not want_over[:, 0].all()      # some rows clip, some do not
    assert np.array_equal(got_over, want_over)
    for c in channels:
        assert np.array_equal(got_codes[c], want_codes[c])
    assert np.any(want_codes["mzi"] != 0) == (mzi_asd > 0)      # the MZI's own noise, when it has one


def test_noise_kernel_gives_the_numpy_generators_bits():
    """synth_kernels.noise_rows against gauss.normal_rows: the same float32 bits for odd and even record
    lengths (the last pair's sine unused) and per-row levels, including a zero one."""
    from sim_devices.world import gauss, synth_kernels as kernels
    for n in (1, 2, 7, 1190, 1191):
        keys = gauss.record_keys(NoiseStream(stream_key(5, 9), 3), 2, 17, "beat_q")
        std = np.linspace(0.0, 3.0, 17)
        want = gauss.normal_rows(keys, n, std)
        got = np.empty((17, n), np.float32)
        kernels.noise_rows(keys, std, got)
        assert np.array_equal(got.view(np.int32), want.view(np.int32))


def test_range_reduction_kernel_gives_the_numpy_passes_values(monkeypatch):
    from sim_devices.world import synth_chunk
    rng = np.random.default_rng(5)
    turns = rng.uniform(-4000.0, 4000.0, (13, 1190))          # a static beat phase in cycles
    turns[0, :6] = [0.5, -0.5, 1.5, 2.5, -2.5, 1e6 + 0.25]    # half-cycle ties and a large phase
    monkeypatch.setattr(synth_jit, "turns_to_radians_f32", lambda samples: None)      # the numpy passes
    want = synth_chunk.cos_sin(turns.copy(), False, True, in_turns=True)[0]
    monkeypatch.setattr(synth_jit, "turns_to_radians_f32", lambda samples: synth_jit._reducer())
    got = synth_chunk.cos_sin(turns.copy(), False, True, in_turns=True)[0]
    assert got.dtype == want.dtype == np.float32
    assert np.array_equal(got.view(np.int32), want.view(np.int32))
