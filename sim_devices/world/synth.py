"""Digitized FMCW beat and monitor-MZI synthesis for a batch of digitizer segments.

Physics (dissertation §2.1 eqs. 2-1..2-5, §2.3, §2.4 eqs. 2-11, 2-13..2-15):

* Laser phase Phi(t) = 2 pi int (nu - nu0) dt + phi_n(t) (+ 2 pi nu0 t, which only enters through the
  delay). The deterministic part comes from :class:`ChirpTrajectory`, computed once per AWG waveform
  on the AWG grid; it is accumulated and evaluated in float64. (With gamma ~ 1e14 Hz/s the chirp
  phase reaches ~1e6 rad over a ramp, where float32 has a 0.06 rad ulp: a float32 pipeline corrupts
  the beat phase by ~0.2 rad rms and up to ~1 rad on single samples; a test shows it. The periodic
  phase is stored with its mean frequency removed so that even float64 never sees the ever-growing
  absolute phase of a long-running virtual clock.)
* An interferometer of delay tau beats Phi(t) against Phi(t - tau). A target at distance d(t) = d + v t
  (v > 0 receding) returns light delayed by tau(t) = 2 d(t) / c, so the LiDAR beat phase is::

      dPhi(t) = Phi(t) - Phi(t - tau(t))
              = [Phi_chirp(t) - Phi_chirp(t - tau(t))] + 2 pi nu0 tau(t) + phi_n(t) - phi_n(t - tau)

  and 2 pi nu0 tau(t) = 2 pi nu0 tau_0 - 2 pi f_D t with the optical Doppler shift of the return
  f_D = -2 v / lambda (``HitBatch.doppler_hz``; receding -> red shift -> f_D < 0). Differentiating, the
  beat frequency is gamma tau - f_D: on the up ramp f_up = 2 gamma d / c + 2 v / lambda and on the down
  ramp the (negative) frequency -2|gamma| d / c + 2 v / lambda, i.e. |f_down| = 2|gamma| d/c - 2 v/lambda.
  With the approaching speed V = -v these are eqs. 2-4 and 2-5 (a test checks this).
* Real beat: A cos(dPhi) (+ dc_v); I/Q beat: I = A cos(dPhi), Q = A sin(dPhi) -- the complex beat
  I + jQ = A exp(+j dPhi), so the up-ramp tone of a static target has a POSITIVE frequency and the
  down-ramp tone a negative one. A = ``HitBatch.amplitude_v`` = G_TIA I_AC (eq. 2-11); its FFT peak
  ASD (eq. 2-13) is A sqrt(T/2) (eq. 2-14 with tau_c = inf).
* Phase noise: ONE Wiener realization per segment on the ADC grid (variance 2 pi linewidth / fs per
  sample), shared by the LiDAR beat and the monitor MZI, so that the MZI carries exactly the phase
  noise that H7's compensation removes. For a delay that is an integer number m of ADC samples the
  beat noise is exactly phi[k] - phi[k - m]. Otherwise phi(t - tau) is the linear interpolation
  between the neighbouring samples plus an independent Brownian-bridge term of variance
  2 pi linewidth dt w (1 - w), which makes Var[phi(t) - phi(t - tau)] = 2 pi linewidth tau exactly.
  (Bridge terms of two different delays in the same sample interval are drawn independently, a
  negligible simplification.) The Doppler change of tau within a segment is ignored for the noise.
* Additive noise: white Gaussian with single-sided ASD ``noise_asd_v_per_rthz`` (shot + RIN + thermal
  + ambient of eqs. 2-16..2-21), per-sample std = ASD sqrt(fs / 2).
* ADC: mid-tread quantizer with LSB = input_range_v / 2**bits; code k means k LSB volts; codes span
  [-2**(bits-1), 2**(bits-1) - 1], i.e. full scale is +-input_range_v / 2 (the budget's V_ADC is the
  full peak-to-peak range, eq. 2-19). Samples beyond are clipped and the channel flagged overrange.

Cost model: work happens at the ADC rate passed in, only for the hits given (a segment without hits
gets noise only), and every switched-off effect (linewidth 0, ASD 0, quantize False, no MZI) is
skipped without drawing random numbers. Everything is vectorized over segments and hits; segments
are processed in chunks (~1 M samples) to bound the temporaries, and hits of one segment are
accumulated by rank (the r-th hit of every segment at once). The deterministic chirp and MZI phases
are computed once per distinct start offset within the drive period (usually one: triggers are
period-aligned). Static returns on a rational AWG/ADC grid (r = p/q, q <= 16) take their delayed
phase from per-residue vectors instead of per-sample gathers (:mod:`sim_devices.world.synth_grid`), and
the white noise is a counter-based float32 draw (:mod:`sim_devices.world.gauss`: a function of the
record's index, not of a generator's state). With quantization
on, cos/sin run in float32 after an exact float64 range reduction (error ~1e-7 of the amplitude,
<< 1 LSB of a 16-bit ADC). The phase noise's random stream is drawn chunk by chunk,
so results are reproducible for the same inputs and seed (not across different chunk sizes); the
white noise of a record depends only on its stream key, record index and channel.
benchmarks/synthesis.py measures ~40 M samples/s per core without phase noise, ~20 M with it.

Parts: the chirp trajectory is ``sim_devices.world.synth_chirp``, the input/output types and
:class:`SynthError` ``sim_devices.world.synth_types``, the work on one chunk of segments (beat, MZI,
noise and ADC) ``sim_devices.world.synth_chunk``; this module checks the inputs, computes what is
computed once per call and walks the chunks.
"""

from __future__ import annotations

import math

import numpy as np

from lidard.physics.constants import C_M_PER_S
from sim_devices.world import antialias
from sim_devices.world.gauss import NoiseStream
from sim_devices.world.laser import wiener_phase
from sim_devices.world.synth_chirp import ChirpTrajectory, trajectory, trajectory_from_frequency
from sim_devices.world.synth_chunk import (
    ChunkRun,
    SortedHits,
    Tables,
    beat_chunk,
    delay_split,
    digitize_chunk,
    mzi_chunk,
)
from sim_devices.world.synth_grid import rational_ratio
from sim_devices.world.synth_types import (
    AdcSpec, Effects, HitBatch, MonitorMzi, SynthError, Synthesized, SynthOutputs,
)

_CHUNK_ELEMENTS = 1 << 20      # samples per chunk of temporaries (~8 MB per float64 array)


# --------------------------------------------------------------------------------------------------
# Synthesis
# --------------------------------------------------------------------------------------------------
def _per_segment(name: str, v, n_seg: int) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.shape == ():
        a = np.full(n_seg, float(a))
    if a.shape != (n_seg,):
        raise SynthError(f"synthesize: {name} must be a scalar or shape ({n_seg},), got {a.shape}")
    if not np.all(np.isfinite(a)) or a.min(initial=0.0) < 0:
        raise SynthError(f"synthesize: {name} must be finite and >= 0")
    return a


def _validated(t_start_s, hits: HitBatch | None, eff: Effects, rng, mzi: MonitorMzi | None, keyed: bool,
               ) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None],
                          np.ndarray]:
    """The arguments of :func:`synthesize` checked (a SynthError names the first bad one):
    (t_start_s, (seg, tau, amp, dop, phase) of the hits, per-segment noise ASD)."""
    t0 = np.asarray(t_start_s, dtype=np.float64)
    if t0.ndim != 1 or not np.all(np.isfinite(t0)):
        raise SynthError(f"synthesize: t_start_s must be a finite 1-D array, got shape {t0.shape}")
    n_seg = t0.size
    hits = hits if hits is not None else HitBatch.empty()
    seg, tau, amp, dop, ph = hits.validated(n_seg)
    asd = _per_segment("noise_asd_v_per_rthz", eff.noise_asd_v_per_rthz, n_seg)
    linewidth_hz = eff.linewidth_hz
    if not (math.isfinite(linewidth_hz) and linewidth_hz >= 0):
        raise SynthError(f"synthesize: linewidth_hz must be >= 0 and finite, got {linewidth_hz!r}")
    if mzi is not None:
        if not (math.isfinite(mzi.delay_s) and mzi.delay_s > 0):
            raise SynthError(f"synthesize: mzi.delay_s must be positive and finite, got {mzi.delay_s!r}")
        if not (math.isfinite(mzi.amplitude_v) and mzi.amplitude_v >= 0):
            raise SynthError(f"synthesize: mzi.amplitude_v must be >= 0 and finite, got {mzi.amplitude_v!r}")
        if not (math.isfinite(mzi.noise_asd_v_per_rthz) and mzi.noise_asd_v_per_rthz >= 0):
            raise SynthError(f"synthesize: mzi.noise_asd_v_per_rthz must be >= 0, got {mzi.noise_asd_v_per_rthz!r}")
    if not math.isfinite(eff.dc_v):
        raise SynthError(f"synthesize: dc_v must be finite, got {eff.dc_v!r}")
    white = asd.max(initial=0) > 0 or (mzi is not None and mzi.noise_asd_v_per_rthz > 0)
    need_rng = (linewidth_hz > 0 and (seg.size or mzi is not None)) or (white and not keyed)
    if need_rng and rng is None:
        raise SynthError("synthesize: rng (numpy Generator) is required when phase noise is on, or white noise "
                         "without a noise stream")
    return t0, (seg, tau, amp, dop, ph), asd


def _sorted_hits(traj: ChirpTrajectory, seg, tau, amp, dop, ph, fs: float) -> SortedHits:
    """Hits sorted by segment, ranked within their segment; a missing phase is 2 pi nu0 tau."""
    order = np.argsort(seg, kind="stable")
    seg, tau, amp, dop = seg[order], tau[order], amp[order], dop[order]
    if ph is None:
        ph = 2.0 * np.pi * np.mod(traj.nu0_hz * tau, 1.0)
    else:
        ph = ph[order]
    first = np.searchsorted(seg, seg, side="left")
    rank = np.arange(seg.size) - first
    m_hit, w_hit = delay_split(tau, fs)
    return SortedHits(seg, tau, amp, dop, ph, rank, m_hit, w_hit, int(rank.max(initial=-1)))


def _tables(traj: ChirpTrajectory, t0: np.ndarray, n: int, fs: float, max_tau_s: float,
            mzi: MonitorMzi | None, hits: str, beat_filter) -> Tables:
    """The deterministic chirp phase on the record grid, once per distinct start offset, and the
    monitor MZI's deterministic phase and clean fringes. ``hits``: "none", "static" (no Doppler) or
    "moving"; static returns on a rational grid from one start offset take the fast path, which
    needs no record-grid chirp phase (synth_chunk._beat_phase)."""
    n_awg = traj.n
    ratio = traj.fs_hz / fs
    x_start = np.mod(t0 * traj.fs_hz, n_awg)
    x_start[x_start >= n_awg] = 0.0
    if x_start.size and x_start.min() == x_start.max():       # triggers period-aligned: one offset
        u_start, u_inv = x_start[:1].copy(), np.zeros(x_start.size, np.intp)
    else:
        u_start, u_inv = np.unique(x_start, return_inverse=True)
    k = np.arange(n, dtype=np.float64)
    max_tau_samples_awg = max(max_tau_s, mzi.delay_s if mzi is not None else 0.0) * traj.fs_hz
    # hits' x - tau fs may go back one period, and a record may span several: tile the tables
    back = int(math.ceil(max_tau_samples_awg / n_awg)) + 1
    periods = back + int(math.ceil((n * ratio + 1) / n_awg)) + 1
    off = back * n_awg
    aa_rate = antialias.trajectory_rates(traj)[1] if beat_filter is not None else 0.0
    # the fast path needs float64 tables (the float32 trajectory exists for the precision test only)
    grid = rational_ratio(ratio) if traj.phase_rad.dtype == np.float64 else None
    fast_hits = hits == "static" and grid is not None and u_start.size == 1
    need_base = mzi is not None or (hits != "none" and not fast_hits)
    base = traj.periodic_phase_samples(u_start[:, None] + off + k * ratio, periods) if need_base else None
    tb = Tables(traj, n, fs, ratio, k, off, periods, u_start, u_inv, u_start.size == 1, grid,
                2.0 * np.pi * traj.mean_hz, aa_rate, base)
    if mzi is not None:
        # the MZI's deterministic phase depends only on the start offset: once per distinct offset
        tau_m = float(mzi.delay_s)
        xm = u_start[:, None] + off + k[None, :] * ratio - tau_m * traj.fs_hz
        tb.mzi_det = base - traj._phase_nonneg(xm, periods)
        tb.mzi_det += tb.mean_w * tau_m + 2.0 * np.pi * math.fmod(traj.nu0_hz * tau_m, 1.0)
        tb.mzi_clean = np.cos(tb.mzi_det) * mzi.amplitude_v
        tb.mzi_clean_q = np.sin(tb.mzi_det) * mzi.amplitude_v if mzi.quadrature else None
    return tb


_NO_EFFECTS = Effects()          # the clean beat
_RECORDS_ONLY = SynthOutputs()   # the records, no volts or phase noise


def synthesize(traj: ChirpTrajectory, adc: AdcSpec, t_start_s, hits: HitBatch | None, *,
               rng: np.random.Generator | None = None, effects: Effects = _NO_EFFECTS, mzi: MonitorMzi | None = None,
               outputs: SynthOutputs = _RECORDS_ONLY, noise: NoiseStream | None = None) -> Synthesized:
    """Synthesize the digitized LiDAR beat (and the monitor MZI) for ``len(t_start_s)`` segments.

    ``t_start_s[s]`` is the time of segment s's first sample on the AWG's time axis (t = 0 at the
    start of a drive period; the drive repeats every ``traj.period_s``). ``hits`` may be None or empty
    (noise only). ``effects``: white noise, phase noise, DC, the anti-alias filter and the I/Q hybrid
    (:class:`Effects`; none by default); ``mzi``: the monitor MZI's channel(s) (:class:`MonitorMzi`;
    None: no MZI); ``outputs``: volts, phase noise and the trig precision (:class:`SynthOutputs`).
    ``rng`` is required only when something random is switched on. Each channel draws its own white
    noise (two photodiodes, two digitizer channels): record s of this call is record
    ``noise.first + s`` of the stream ``noise`` (:mod:`sim_devices.world.gauss`: the same record
    index, key and channel give the same noise, whatever the call); without one, white noise is
    drawn from a stream keyed by one draw of ``rng``, taken before the phase noise's draws.
    """
    linewidth_hz, dc_v = effects.linewidth_hz, effects.dc_v
    beat_filter, iq_imbalance = effects.beat_filter, effects.iq_imbalance
    return_volts, return_phase_noise, fast_trig = outputs.volts, outputs.phase_noise, outputs.fast_trig
    fast = adc.quantize if fast_trig is None else bool(fast_trig)
    t0, raw_hits, asd = _validated(t_start_s, hits, effects, rng, mzi, noise is not None)
    if noise is None and (asd.max(initial=0) > 0 or (mzi is not None and mzi.noise_asd_v_per_rthz > 0)):
        assert rng is not None          # _validated requires one
        noise = NoiseStream.from_rng(rng)
    n_seg, n, fs = t0.size, int(adc.n_samples), float(adc.sample_rate_hz)
    want_mzi = mzi is not None
    mzi_quadrature = mzi is not None and mzi.quadrature
    h = _sorted_hits(traj, *raw_hits, fs)
    kind = "none" if h.seg.size == 0 else "moving" if np.any(h.dop != 0.0) else "static"
    tb = _tables(traj, t0, n, fs, float(h.tau.max(initial=0.0)), mzi, kind, beat_filter)

    # -- phase-noise geometry ----------------------------------------------------------------------
    pn_on = linewidth_hz > 0 and (h.seg.size > 0 or want_mzi)
    var_step = 2.0 * np.pi * linewidth_hz / fs
    pn_rng = rng if pn_on else None      # _validated requires an rng when phase noise is on
    m_mzi, w_mzi = delay_split(np.array([mzi.delay_s]), fs) if mzi is not None else (None, None)
    n_pre = max(int(h.m.max(initial=0)), int(m_mzi[0]) if m_mzi is not None else 0) + 1

    channels = ["beat"] + (["beat_q"] if adc.iq else []) + (["mzi"] if want_mzi else []) \
        + (["mzi_q"] if want_mzi and mzi_quadrature else [])
    out_dtype = np.int16 if adc.quantize else np.float64
    outs = {c: np.empty((n_seg, n), dtype=out_dtype) for c in channels}
    overrange = np.zeros((n_seg, len(channels)), dtype=bool)
    volts = {c: np.empty((n_seg, n)) for c in channels} if return_volts else None
    pn_all = np.empty((n_seg, n_pre + n)) if (return_phase_noise and pn_on) else None

    chunk = max(1, _CHUNK_ELEMENTS // max(n, 1))
    seg_bounds = np.searchsorted(h.seg, np.arange(0, n_seg + chunk, chunk))
    noise_std = asd * math.sqrt(fs / 2.0)
    run = ChunkRun(tb=tb, adc=adc, fast=fast, rng=rng, var_step=var_step, n_pre=n_pre, iq_imbalance=iq_imbalance,
                   beat_filter=beat_filter, quadrature=mzi_quadrature,
                   mzi_amplitude_v=mzi.amplitude_v if mzi is not None else None, m_mzi=m_mzi, w_mzi=w_mzi, dc_v=dc_v,
                   noise_std=noise_std, mzi_noise_asd_v_per_rthz=mzi.noise_asd_v_per_rthz if mzi is not None else 0.0,
                   noise=noise)
    for ci, s0 in enumerate(range(0, n_seg, chunk)):
        s1 = min(n_seg, s0 + chunk)
        nc = s1 - s0
        h0, h1 = int(seg_bounds[ci]), int(seg_bounds[ci + 1])
        phi = wiener_phase(linewidth_hz, n_pre + n, 1.0 / fs, pn_rng, shape=(nc,)) if pn_rng is not None else None
        if pn_all is not None:
            pn_all[s0:s1] = phi
        acc = {}
        if h1 > h0:
            acc = beat_chunk(run, h, slice(h0, h1), s0, nc, phi)
        for c in channels:
            if c not in ("mzi", "mzi_q") and c not in acc:
                acc[c] = np.zeros((nc, n), dtype=np.float32 if fast else np.float64)
        if want_mzi:
            acc.update(mzi_chunk(run, s0, s1, phi))
        digitize_chunk(run, acc, channels, s0, s1, outs, overrange, volts)

    return Synthesized(beat=outs["beat"], beat_q=outs.get("beat_q"), mzi=outs.get("mzi"),
                       overrange=overrange, channels=tuple(channels), lsb_v=adc.lsb_v, volts=volts,
                       phase_noise_rad=pn_all, phase_noise_pre=n_pre if pn_all is not None else 0,
                       mzi_q=outs.get("mzi_q"))


def sample_rate_for_range_hz(max_range_m: float, rate_hz_per_s: float, *, oversample: float = 2.5,
                             max_doppler_hz: float = 0.0) -> float:
    """ADC rate that captures beats up to 2 gamma d_max / c (+ Doppler) with ``oversample`` x Nyquist."""
    if not (max_range_m > 0 and rate_hz_per_s > 0 and oversample >= 1):
        raise SynthError("sample_rate_for_range_hz: max_range_m, rate_hz_per_s > 0 and oversample >= 1 required")
    f_max = 2.0 * abs(rate_hz_per_s) * max_range_m / C_M_PER_S + abs(max_doppler_hz)
    return oversample * 2.0 * f_max


__all__ = ["AdcSpec", "ChirpTrajectory", "Effects", "HitBatch", "MonitorMzi", "NoiseStream", "SynthError", "SynthOutputs",
           "Synthesized", "sample_rate_for_range_hz", "synthesize", "trajectory", "trajectory_from_frequency"]
