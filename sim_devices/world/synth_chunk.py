"""One chunk of segments of the beat synthesis (``sim_devices.world.synth``): the LiDAR beat of
every hit, the monitor MZI, white noise and the ADC (dissertation §2.1 eqs. 2-1..2-5, §2.3, §2.4
eqs. 2-11, 2-13..2-21; the physics and the cost model are in synth's docstring).

:func:`synthesize <sim_devices.world.synth.synthesize>` validates its inputs, sorts the hits and
computes the deterministic phases once (:class:`Tables`, :class:`SortedHits`), then walks the
segments in chunks of about 1 M samples: per chunk it draws the Wiener phase noise, then
:func:`beat_chunk` (hits accumulated by rank), :func:`mzi_chunk` and :func:`digitize_chunk`
(noise, dc, quantization, clipping), in that order, so the random stream is the same as in one loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim_devices.world import antialias, synth_jit
from sim_devices.world.gauss import NoiseStream, normal_rows, record_keys
from sim_devices.world.synth_chirp import ChirpTrajectory
from sim_devices.world.synth_grid import static_beat_phase
from sim_devices.world.synth_types import AdcSpec

_INTEGER_DELAY_TOL = 1e-6      # in ADC samples: a delay this close to m / fs is treated as exact
_NO_NOISE = np.zeros((1, 1), np.float32)    # the quantizer kernel's noise argument when there is none


@dataclass
class Tables:
    """What one synthesis computes once: the record grid on the AWG axis (``ratio`` AWG samples per
    ADC sample, tables tiled over ``periods`` drive periods from ``off``), the distinct start offsets
    (``u_start``, ``u_inv``: segment -> offset), the deterministic chirp phase per offset (``base``),
    the rational-grid fast path (``grid``) and the monitor MZI's clean phase and fringes."""

    traj: ChirpTrajectory
    n: int
    fs: float
    ratio: float
    k: np.ndarray
    off: int
    periods: int
    u_start: np.ndarray
    u_inv: np.ndarray
    single_start: bool
    grid: tuple[int, int] | None
    mean_w: float
    aa_rate: float
    base: np.ndarray | None
    mzi_det: np.ndarray | None = None
    mzi_clean: np.ndarray | None = None
    mzi_clean_q: np.ndarray | None = None


@dataclass
class SortedHits:
    """The hits sorted by segment (stable), each with its rank within its segment and its delay split
    into whole ADC samples ``m`` and a fraction ``w`` (:func:`delay_split`)."""

    seg: np.ndarray
    tau: np.ndarray
    amp: np.ndarray
    dop: np.ndarray
    ph: np.ndarray
    rank: np.ndarray
    m: np.ndarray
    w: np.ndarray
    max_rank: int


def delay_split(tau_s: np.ndarray, fs: float):
    """Delay in ADC samples -> (m = ceil, w = m - tau fs in [0, 1)); w < tol counts as integer."""
    x = tau_s * fs
    m = np.ceil(x - _INTEGER_DELAY_TOL)
    w = m - x
    w[w < _INTEGER_DELAY_TOL] = 0.0
    return m.astype(np.intp), w


def delayed_noise(phi, rows, n_pre, n, m, w, var_step, rng):
    """phi(t_k - tau) for records `rows` of phi (n_rows, n_pre+n), tau fs = m - w: exact for w == 0,
    else linear interpolation between samples k - m and k - m + 1 plus a Brownian-bridge term."""
    win = np.lib.stride_tricks.sliding_window_view(phi, n, axis=1)    # win[r, j] = phi[r, j:j+n]
    out = win[rows, n_pre - m]                                        # contiguous row copies
    frac = np.nonzero(w > 0)[0]
    if frac.size:
        ww = w[frac][:, None]
        step = win[rows[frac], n_pre - m[frac] + 1]
        step -= out[frac]
        step *= ww
        step += rng.standard_normal((frac.size, n)) * np.sqrt(var_step * ww * (1.0 - ww))
        out[frac] += step
    return out


def cos_sin(phase: np.ndarray, want_sin: bool, fast: bool, in_turns: bool = False):
    """cos (and sin) of a float64 phase array, which may be consumed.

    ``fast``: reduce to [-pi, pi] in float64, then evaluate in float32 (SIMD, ~20x faster than the
    float64 libm path here) and answer float32: absolute error ~1e-7, far below one LSB of a 16-bit
    ADC (1.5e-5 of full scale), so it is used only when the output is quantized.
    ``in_turns`` (fast only): ``phase`` is in cycles, |phase| < 2**24 (the static fast path's phase
    is a difference of chirp phases, a few thousand cycles at most), so the whole number of cycles
    fits a float32 buffer exactly, which then takes the reduced phase (no float64 temporary).
    """
    if not fast:
        s = np.sin(phase) if want_sin else None
        return np.cos(phase, out=phase), s
    reduce = synth_jit.turns_to_radians_f32(phase.size) if in_turns and phase.flags.c_contiguous else None
    if reduce is not None:          # the three passes below in one compiled pass, the same values
        r32 = np.empty(phase.shape, np.float32)
        reduce(phase.reshape(-1), r32.reshape(-1))
    elif in_turns:
        r32 = np.rint(phase, out=np.empty(phase.shape, np.float32), casting="same_kind")
        phase -= r32
        np.multiply(phase, 2.0 * np.pi, out=r32, casting="same_kind")   # float64 product, stored float32
    else:
        phase *= 1.0 / (2.0 * np.pi)
        turns = np.rint(phase)
        phase -= turns
        del turns
        phase *= 2.0 * np.pi
        r32 = phase.astype(np.float32)
    # the record stays float32 from here (amplitude, filter gains, noise): 7 digits against the
    # 16-bit converter's 4.6, and half the memory traffic of float64
    c = np.cos(r32, out=r32) if not want_sin else np.cos(r32)
    s = np.sin(r32, out=r32) if want_sin else None
    return c, s


def _beat_phase(tb: Tables, h: SortedHits, hs: slice, fast: bool, phi_on: bool):
    """The deterministic beat phase dPhi of hits ``hs`` on the record grid (radians, or cycles
    when ``in_turns``), and ``in_turns``."""
    traj, k, off, periods, ratio = tb.traj, tb.k, tb.off, tb.periods, tb.ratio
    tau, dop = h.tau, h.dop
    useg = tb.u_inv[h.seg[hs]]
    # + 2 pi nu_mean tau(t) + phase0 - 2 pi f_D t  (constant + linear in k per hit)
    const = tb.mean_w * tau[hs] + h.ph[hs]
    slope = -(tb.mean_w / traj.nu0_hz + 2.0 * np.pi) * dop[hs] / tb.fs
    moving = bool(np.any(slope != 0.0))
    # in turns (cycles) where nothing in radians is added: the float32 trig's range
    # reduction then starts from turns (one pass fewer); the phase is linear in the tables
    in_turns = fast and not phi_on and tb.grid is not None and tb.single_start and not moving
    if tb.grid is not None and tb.single_start and not moving:
        # static returns on a rational grid: no per-sample gathers (synth_grid)
        tables, c = (traj._tiled_turns(periods), const / (2.0 * np.pi)) if in_turns \
            else (traj._tiled(periods), const)
        dphi = static_beat_phase(tables, float(tb.u_start[0]) + off, ratio, tb.grid, tb.n,
                                 tau[hs] * traj.fs_hz, c)
    else:
        # delayed position x = x_start + k ratio - tau(t) fs_awg with the Doppler-varying delay
        # tau(t) = tau0 - (f_D / nu0) t, t = k / fs: linear in k per hit
        x = np.multiply.outer(ratio + dop[hs] * (traj.fs_hz / (traj.nu0_hz * tb.fs)), k)
        x += (tb.u_start[useg] + off - tau[hs] * traj.fs_hz)[:, None]
        dphi = traj._phase_nonneg(x, periods)
        del x
        base = tb.base
        assert base is not None         # computed whenever there are hits (synth._tables)
        np.subtract(base[0] if tb.single_start else base[useg], dphi, out=dphi)
        if moving:
            lin = np.multiply.outer(slope, k)
            lin += const[:, None]
            dphi += lin
            del lin
        else:
            dphi += const[:, None]
    return dphi, in_turns


#: relative and absolute (Hz) margins of the anti-alias column screen over its bound: far above the
#: rounding of a beat frequency estimated from float64 phases (~1e-4 Hz)
_SCREEN_REL, _SCREEN_HZ = 1e-6, 1e3


def _filter_gains(tb: Tables, h: SortedHits, hs: slice, dphi: np.ndarray, in_turns: bool,
                  beat_filter: antialias.BeatFilter):
    """antialias.sample_gains of the hits ``hs``: only the returns and, when every record starts at one
    offset, only the samples whose beat may leave the pass band (antialias.column_rates)."""
    tau, dop = h.tau[hs], np.abs(h.dop[hs])
    bound = tau * tb.aa_rate + dop
    may = bound > beat_filter.passband_hz
    if not may.any():
        return None
    cols = None
    if tb.single_start:
        traj = tb.traj
        tau_max, dop_max = float(tau[may].max()), float(dop[may].max())
        # the Doppler's change of the delay over a record, in AWG samples, widens the reach
        reach = tau_max * traj.fs_hz + dop_max * traj.fs_hz / traj.nu0_hz * tb.n / tb.fs
        rates = antialias.column_rates(traj, float(tb.u_start[0]) + tb.off, tb.ratio, tb.n, reach)
        edge = tau_max * rates * (1.0 + _SCREEN_REL) + dop_max + _SCREEN_HZ
        cols = np.flatnonzero(edge > beat_filter.passband_hz)
    return antialias.sample_gains(dphi, tb.fs, beat_filter, bound, turns=in_turns, cols=cols)


@dataclass(frozen=True)
class ChunkRun:
    """What every chunk of one synthesis shares: the tables, the ADC, the float32 trig path (``fast``),
    the random stream of the phase noise, its variance per sample (``var_step``) and pre-roll (``n_pre``
    samples), the receiver (``iq_imbalance`` (g, eps), the anti-alias ``beat_filter``), the monitor MZI
    (``quadrature`` output, ``mzi_amplitude_v``, its delay split ``m_mzi``/``w_mzi``; None without an
    MZI), the beat channels' ``dc_v``, the beat's white-noise std per segment, the MZI's noise ASD and
    the white noise's stream (``noise``; None when no white noise is on)."""

    tb: Tables
    adc: AdcSpec
    fast: bool
    rng: np.random.Generator | None
    var_step: float
    n_pre: int
    iq_imbalance: tuple[float, float]
    beat_filter: antialias.BeatFilter | None
    quadrature: bool
    mzi_amplitude_v: float | None
    m_mzi: np.ndarray | None
    w_mzi: np.ndarray | None
    dc_v: float
    noise_std: np.ndarray
    mzi_noise_asd_v_per_rthz: float
    noise: NoiseStream | None = None


def beat_chunk(run: ChunkRun, h: SortedHits, hs: slice, s0: int, nc: int, phi: np.ndarray | None) -> dict:
    """The beat channels ("beat", and "beat_q" for I/Q) of the ``nc`` segments from ``s0``, from
    the hits ``hs`` (all in those segments): one tone per hit, summed per segment by rank."""
    tb, n_pre, var_step, rng, fast, adc = run.tb, run.n_pre, run.var_step, run.rng, run.fast, run.adc
    iq_imbalance, beat_filter = run.iq_imbalance, run.beat_filter
    n = tb.n
    lseg = h.seg[hs] - s0
    dphi, in_turns = _beat_phase(tb, h, hs, fast, phi is not None)
    # before phase noise: the filter sees the chirp's beat
    aa = None if beat_filter is None else _filter_gains(tb, h, hs, dphi, in_turns, beat_filter)
    if phi is not None:
        dphi += phi[lseg, n_pre:]
        dphi -= delayed_noise(phi, lseg, n_pre, n, h.m[hs], h.w[hs], var_step, rng)
    a = h.amp[hs, None]
    parts = {}
    cos_part, sin_part = cos_sin(dphi, adc.iq, fast, in_turns=in_turns)
    del dphi
    if adc.iq and iq_imbalance[1]:   # sin(dPhi + eps) from the same cos and sin: no second evaluation
        sin_part *= math.cos(iq_imbalance[1])
        sin_part += math.sin(iq_imbalance[1]) * cos_part
    cos_part *= a
    if aa is not None:
        cos_part[aa[0], aa[1]] *= aa[2]
    parts["beat"] = cos_part
    if adc.iq:
        sin_part *= a * iq_imbalance[0]
        if aa is not None:
            sin_part[aa[0], aa[1]] *= aa[2]
        parts["beat_q"] = sin_part
    return _by_rank(parts, h.rank[hs], lseg, h.max_rank, hs.stop - hs.start, nc, n)


def _by_rank(parts: dict, rk: np.ndarray, lseg: np.ndarray, max_rank: int, nh: int, nc: int,
             n: int) -> dict:
    """Per channel, the hits' tones summed into their segments: the r-th hit of every segment at once."""
    acc = {}
    dense = max_rank == 0 and nh == nc          # one hit in every segment (sorted): no scatter
    for c, part in parts.items():
        if dense:
            acc[c] = part
            continue
        first = np.nonzero(rk == 0)[0]
        # every segment has a hit: the first hits, in segment order, are the sum's first term
        covered = first.size == nc
        acc[c] = part[first] if covered else np.zeros((nc, n), dtype=part.dtype)
        for r in range(0 if not covered else 1, max_rank + 1):
            sel = first if r == 0 else np.nonzero(rk == r)[0]
            if sel.size == 0:
                continue
            if r == 0:
                acc[c][lseg[sel]] = part[sel]
            else:
                acc[c][lseg[sel]] += part[sel]
    return acc


def mzi_chunk(run: ChunkRun, s0: int, s1: int, phi: np.ndarray | None) -> dict:
    """The monitor MZI ("mzi", and "mzi_q" with the quadrature output) of segments s0..s1-1: the
    clean fringes, or with phase noise the same Wiener realization as the beat's, delayed by the
    MZI's delay."""
    tb, n_pre, var_step, rng, fast, quadrature = run.tb, run.n_pre, run.var_step, run.rng, run.fast, run.quadrature
    amplitude_v, m_mzi, w_mzi = run.mzi_amplitude_v, run.m_mzi, run.w_mzi
    # given whenever an MZI is synthesized (synth._validated)
    assert amplitude_v is not None and m_mzi is not None and w_mzi is not None
    nc, n = s1 - s0, tb.n
    single_start, mzi_det = tb.single_start, tb.mzi_det
    acc = {}
    ub = tb.u_inv[s0:s1]
    # the tables hold the MZI's phase and fringes whenever an MZI is synthesized (synth._tables)
    assert mzi_det is not None and tb.mzi_clean is not None
    if phi is not None:
        mphi = mzi_det[0] + phi[:, n_pre:] if single_start else mzi_det[ub] + phi[:, n_pre:]
        mphi -= delayed_noise(phi, np.arange(nc), n_pre, n, np.full(nc, m_mzi[0]),
                              np.full(nc, w_mzi[0]), var_step, rng)
        mzi_v, mzi_s = cos_sin(mphi, quadrature, fast)
        mzi_v *= amplitude_v
        acc["mzi"] = mzi_v
        if quadrature:       # the same MZI's 90-degree output: same phase noise, sin
            acc["mzi_q"] = mzi_s * amplitude_v
    else:
        acc["mzi"] = np.repeat(tb.mzi_clean, nc, axis=0) if single_start else tb.mzi_clean[ub]
        if quadrature:
            assert tb.mzi_clean_q is not None
            acc["mzi_q"] = np.repeat(tb.mzi_clean_q, nc, axis=0) if single_start else tb.mzi_clean_q[ub]
    return acc


def digitize_chunk(run: ChunkRun, acc: dict, channels: list[str], s0: int, s1: int, outs: dict,
                   overrange: np.ndarray, volts: dict | None) -> None:
    """Add white noise (and ``dc_v`` on the beat channels) to each channel of segments s0..s1-1,
    then quantize (or keep volts), flag overrange and clip into ``outs``/``overrange``/``volts``.
    The noise of record s of a channel is gauss.normal_rows of its key (``run.noise``): the compiled
    quantizer draws it in its own pass, the numpy path as an array; the same values."""
    adc, dc_v, noise_std = run.adc, run.dc_v, run.noise_std
    nc, n, fs = s1 - s0, int(adc.n_samples), float(adc.sample_rate_hz)
    for c in channels:
        v = acc[c]
        if c in ("mzi", "mzi_q"):
            std = np.full(nc, run.mzi_noise_asd_v_per_rthz * math.sqrt(fs / 2.0))
        else:
            if dc_v:
                v += dc_v
            std = noise_std[s0:s1]
        keys = None
        if std.max(initial=0.0) > 0:
            assert run.noise is not None        # synth.synthesize keys a stream whenever a noise is on
            keys = record_keys(run.noise, s0, nc, c)
        j = channels.index(c)
        kernel = None
        if adc.quantize and volts is None and v.dtype == np.float32 and outs[c].dtype == np.int16:
            kernel = synth_jit.quantize_rows(v.size, noisy=keys is not None)
        if kernel is not None:      # noise, scale, rounding, flags and clip in one compiled pass
            over = np.empty(nc, dtype=bool)
            q = (np.float32(1.0 / adc.lsb_v), np.float32(adc.code_min), np.float32(adc.code_max), outs[c][s0:s1], over)
            if keys is None:
                kernel(v, _NO_NOISE, False, *q)
            else:
                kernel(v, keys, np.ascontiguousarray(std, dtype=np.float64), *q)
            overrange[s0:s1, j] = over
            continue
        if keys is not None:
            v += normal_rows(keys, n, std)
        if volts is not None:
            volts[c][s0:s1] = v
        lo: float
        hi: float
        if adc.quantize:
            v *= 1.0 / adc.lsb_v
            np.rint(v, out=v)
            lo, hi = adc.code_min, adc.code_max
        else:
            lo, hi = -adc.input_range_v / 2.0, adc.input_range_v / 2.0
        overrange[s0:s1, j] = (v.min(axis=1) < lo) | (v.max(axis=1) > hi)
        np.clip(v, lo, hi, out=v)
        outs[c][s0:s1] = v
