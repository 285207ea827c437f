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
the white noise is a float32 Box-Muller draw (:mod:`sim_devices.world.gauss`). With quantization
on, cos/sin run in float32 after an exact float64 range reduction (error ~1e-7 of the amplitude,
<< 1 LSB of a 16-bit ADC). The random stream is drawn chunk by chunk,
so results are reproducible for the same inputs and seed (not across different chunk sizes).
benchmarks/synthesis.py measures ~40 M samples/s per core without phase noise, ~20 M with it.

Parts: the chirp trajectory is ``sim_devices.world.synth_chirp``, the input/output types and
:class:`SynthError` ``sim_devices.world.synth_types``; this module is the synthesis itself.
"""

from __future__ import annotations

import math

import numpy as np

from lidard.physics.constants import C_M_PER_S
from sim_devices.world import antialias
from sim_devices.world.gauss import standard_normal_f32
from sim_devices.world.laser import wiener_phase
from sim_devices.world.synth_chirp import ChirpTrajectory, trajectory, trajectory_from_frequency
from sim_devices.world.synth_grid import rational_ratio, static_beat_phase
from sim_devices.world.synth_types import AdcSpec, HitBatch, SynthError, Synthesized

_CHUNK_ELEMENTS = 1 << 20      # samples per chunk of temporaries (~8 MB per float64 array)
_INTEGER_DELAY_TOL = 1e-6      # in ADC samples: a delay this close to m / fs is treated as exact


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


def _delay_split(tau_s: np.ndarray, fs: float):
    """Delay in ADC samples -> (m = ceil, w = m - tau fs in [0, 1)); w < tol counts as integer."""
    x = tau_s * fs
    m = np.ceil(x - _INTEGER_DELAY_TOL)
    w = m - x
    w[w < _INTEGER_DELAY_TOL] = 0.0
    return m.astype(np.intp), w


def _delayed_noise(phi, rows, n_pre, n, m, w, var_step, rng):
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


def _cos_sin(phase: np.ndarray, want_sin: bool, fast: bool, in_turns: bool = False):
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
    if in_turns:
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
    # 16-bit converter's 4.6, and half the memory traffic of float64 (issue 18)
    c = np.cos(r32, out=r32) if not want_sin else np.cos(r32)
    s = np.sin(r32, out=r32) if want_sin else None
    return c, s


def synthesize(traj: ChirpTrajectory, adc: AdcSpec, t_start_s, hits: HitBatch | None, *,
               noise_asd_v_per_rthz=0.0, linewidth_hz: float = 0.0, rng: np.random.Generator | None = None,
               mzi_delay_s: float | None = None, mzi_amplitude_v: float | None = None,
               mzi_noise_asd_v_per_rthz: float = 0.0, dc_v: float = 0.0,
               return_volts: bool = False, return_phase_noise: bool = False, mzi_quadrature: bool = False,
               fast_trig: bool | None = None, beat_filter: antialias.BeatFilter | None = None,
               iq_imbalance: tuple[float, float] = (1.0, 0.0)) -> Synthesized:
    """Synthesize the digitized LiDAR beat (and the monitor MZI) for ``len(t_start_s)`` segments.

    ``t_start_s[s]`` is the time of segment s's first sample on the AWG's time axis (t = 0 at the
    start of a drive period; the drive repeats every ``traj.period_s``). ``hits`` may be None or empty
    (noise only). ``noise_asd_v_per_rthz``: scalar or per-segment white-noise ASD of the LiDAR channel.
    ``rng`` is required only when something random is switched on.
    ``mzi_quadrature``: also the monitor MZI's quadrature output (channel ``mzi_q``: sin of the same
    phase, as a 90-degree hybrid or 3x3 coupler and a second digitizer channel give; its own noise draws).
    ``fast_trig`` (default: ``adc.quantize``) evaluates cos/sin in float32 after an exact float64
    range reduction (error ~1e-7 of the amplitude, invisible after quantization); unquantized output
    uses float64 trig so that tests can compare volts to 1e-9.
    ``beat_filter``: the digitizer's anti-alias filter at each return's true beat frequency
    (:mod:`sim_devices.world.antialias`); None: an ideal one (nothing beyond fs/2 is synthesized).
    ``iq_imbalance``: (g, eps) of the coherent receiver's 90-degree hybrid and photodiode pair: the Q
    channel is g A sin(dPhi + eps) (lidard.dsp.iqbalance); (1, 0) is an ideal hybrid. Each channel
    draws its own white noise (two photodiodes, two digitizer channels).
    """
    fast = adc.quantize if fast_trig is None else bool(fast_trig)
    t0 = np.asarray(t_start_s, dtype=np.float64)
    if t0.ndim != 1 or not np.all(np.isfinite(t0)):
        raise SynthError(f"synthesize: t_start_s must be a finite 1-D array, got shape {t0.shape}")
    n_seg, n, fs = t0.size, int(adc.n_samples), float(adc.sample_rate_hz)
    hits = hits if hits is not None else HitBatch.empty()
    seg, tau, amp, dop, ph = hits.validated(n_seg)
    asd = _per_segment("noise_asd_v_per_rthz", noise_asd_v_per_rthz, n_seg)
    if not (math.isfinite(linewidth_hz) and linewidth_hz >= 0):
        raise SynthError(f"synthesize: linewidth_hz must be >= 0 and finite, got {linewidth_hz!r}")
    want_mzi = mzi_delay_s is not None
    if want_mzi:
        if not (math.isfinite(mzi_delay_s) and mzi_delay_s > 0):
            raise SynthError(f"synthesize: mzi_delay_s must be positive and finite, got {mzi_delay_s!r}")
        if mzi_amplitude_v is None or not (math.isfinite(mzi_amplitude_v) and mzi_amplitude_v >= 0):
            raise SynthError(f"synthesize: mzi_amplitude_v must be given (>= 0) with mzi_delay_s, got {mzi_amplitude_v!r}")
    if not (math.isfinite(mzi_noise_asd_v_per_rthz) and mzi_noise_asd_v_per_rthz >= 0):
        raise SynthError(f"synthesize: mzi_noise_asd_v_per_rthz must be >= 0, got {mzi_noise_asd_v_per_rthz!r}")
    if not math.isfinite(dc_v):
        raise SynthError(f"synthesize: dc_v must be finite, got {dc_v!r}")
    need_rng = (linewidth_hz > 0 and (seg.size or want_mzi)) or asd.max(initial=0) > 0 \
        or (want_mzi and mzi_noise_asd_v_per_rthz > 0)
    if need_rng and rng is None:
        raise SynthError("synthesize: rng (numpy Generator) is required when noise or phase noise is on")

    # -- sort hits by segment, rank them within their segment --------------------------------------
    order = np.argsort(seg, kind="stable")
    seg, tau, amp, dop = seg[order], tau[order], amp[order], dop[order]
    if ph is None:
        ph = 2.0 * np.pi * np.mod(traj.nu0_hz * tau, 1.0)
    else:
        ph = ph[order]
    first = np.searchsorted(seg, seg, side="left")
    rank = np.arange(seg.size) - first

    # -- deterministic chirp phase on the record grid, once per distinct start offset --------------
    n_awg = traj.n
    ratio = traj.fs_hz / fs
    x_start = np.mod(t0 * traj.fs_hz, n_awg)
    x_start[x_start >= n_awg] = 0.0
    u_start, u_inv = np.unique(x_start, return_inverse=True)
    k = np.arange(n, dtype=np.float64)
    max_tau_samples_awg = max(float(tau.max(initial=0.0)), mzi_delay_s or 0.0) * traj.fs_hz
    # hits' x - tau fs may go back one period, and a record may span several: tile the tables
    back = int(math.ceil(max_tau_samples_awg / n_awg)) + 1
    periods = back + int(math.ceil((n * ratio + 1) / n_awg)) + 1
    off = back * n_awg
    mean_w = 2.0 * np.pi * traj.mean_hz
    aa_rate = antialias.max_chirp_rate_hz_per_s(traj.nu_hz, traj.fs_hz) if beat_filter is not None else 0.0
    need_base = seg.size > 0 or want_mzi
    base = traj.periodic_phase_samples(u_start[:, None] + off + k * ratio, periods) if need_base else None
    single_start = u_start.size == 1
    # the fast path needs float64 tables (the float32 trajectory exists for the precision test only)
    grid = rational_ratio(ratio) if traj.phase_rad.dtype == np.float64 else None
    if want_mzi:
        # the MZI's deterministic phase depends only on the start offset: once per distinct offset
        tau_m = float(mzi_delay_s)
        xm = u_start[:, None] + off + k[None, :] * ratio - tau_m * traj.fs_hz
        mzi_det = base - traj._phase_nonneg(xm, periods)
        mzi_det += mean_w * tau_m + 2.0 * np.pi * math.fmod(traj.nu0_hz * tau_m, 1.0)
        mzi_clean = np.cos(mzi_det) * mzi_amplitude_v
        mzi_clean_q = np.sin(mzi_det) * mzi_amplitude_v if mzi_quadrature else None

    # -- phase-noise geometry ----------------------------------------------------------------------
    pn_on = linewidth_hz > 0 and (seg.size > 0 or want_mzi)
    var_step = 2.0 * np.pi * linewidth_hz / fs
    m_hit, w_hit = _delay_split(tau, fs)
    if want_mzi:
        m_mzi, w_mzi = _delay_split(np.array([mzi_delay_s]), fs)
    max_m = max(int(m_hit.max(initial=0)), int(m_mzi[0]) if want_mzi else 0)
    n_pre = max_m + 1

    channels = ["beat"] + (["beat_q"] if adc.iq else []) + (["mzi"] if want_mzi else []) \
        + (["mzi_q"] if want_mzi and mzi_quadrature else [])
    out_dtype = np.int16 if adc.quantize else np.float64
    outs = {c: np.empty((n_seg, n), dtype=out_dtype) for c in channels}
    overrange = np.zeros((n_seg, len(channels)), dtype=bool)
    volts = {c: np.empty((n_seg, n)) for c in channels} if return_volts else None
    pn_all = np.empty((n_seg, n_pre + n)) if (return_phase_noise and pn_on) else None

    chunk = max(1, _CHUNK_ELEMENTS // max(n, 1))
    seg_bounds = np.searchsorted(seg, np.arange(0, n_seg + chunk, chunk))
    max_rank = int(rank.max(initial=-1))
    noise_std = asd * math.sqrt(fs / 2.0)
    for ci, s0 in enumerate(range(0, n_seg, chunk)):
        s1 = min(n_seg, s0 + chunk)
        nc = s1 - s0
        h0, h1 = int(seg_bounds[ci]), int(seg_bounds[ci + 1])
        phi = wiener_phase(linewidth_hz, n_pre + n, 1.0 / fs, rng, shape=(nc,)) if pn_on else None
        if pn_all is not None:
            pn_all[s0:s1] = phi

        acc = {}
        if h1 > h0:
            hs = slice(h0, h1)
            nh = h1 - h0
            lseg = seg[hs] - s0
            useg = u_inv[seg[hs]]
            # + 2 pi nu_mean tau(t) + phase0 - 2 pi f_D t  (constant + linear in k per hit)
            const = mean_w * tau[hs] + ph[hs]
            slope = -(mean_w / traj.nu0_hz + 2.0 * np.pi) * dop[hs] / fs
            moving = bool(np.any(slope != 0.0))
            # in turns (cycles) where nothing in radians is added: the float32 trig's range
            # reduction then starts from turns (one pass fewer); the phase is linear in the tables
            in_turns = fast and phi is None and grid is not None and single_start and not moving
            if grid is not None and single_start and not moving:
                # static returns on a rational grid: no per-sample gathers (synth_grid)
                tables, c = (traj._tiled_turns(periods), const / (2.0 * np.pi)) if in_turns \
                    else (traj._tiled(periods), const)
                dphi = static_beat_phase(tables, float(u_start[0]) + off, ratio, grid, n, tau[hs] * traj.fs_hz, c)
            else:
                # delayed position x = x_start + k ratio - tau(t) fs_awg with the Doppler-varying delay
                # tau(t) = tau0 - (f_D / nu0) t, t = k / fs: linear in k per hit
                x = np.multiply.outer(ratio + dop[hs] * (traj.fs_hz / (traj.nu0_hz * fs)), k)
                x += (u_start[useg] + off - tau[hs] * traj.fs_hz)[:, None]
                dphi = traj._phase_nonneg(x, periods)
                del x
                np.subtract(base[0] if single_start else base[useg], dphi, out=dphi)
                if moving:
                    lin = np.multiply.outer(slope, k)
                    lin += const[:, None]
                    dphi += lin
                    del lin
                else:
                    dphi += const[:, None]
            aa = None
            if beat_filter is not None:   # before phase noise: the filter sees the chirp's beat
                bound = tau[hs] * aa_rate + np.abs(dop[hs])
                aa = antialias.sample_gains(dphi, fs, beat_filter, bound, turns=in_turns)
            if phi is not None:
                dphi += phi[lseg, n_pre:]
                dphi -= _delayed_noise(phi, lseg, n_pre, n, m_hit[hs], w_hit[hs], var_step, rng)
            a = amp[hs, None]
            parts = {}
            cos_part, sin_part = _cos_sin(dphi, adc.iq, fast, in_turns=in_turns)
            del dphi
            if adc.iq and iq_imbalance[1]:   # sin(dPhi + eps) from the same cos and sin: no second evaluation
                sin_part *= math.cos(iq_imbalance[1])
                sin_part += math.sin(iq_imbalance[1]) * cos_part
            cos_part *= a
            if aa is not None:
                cos_part[aa[0]] *= aa[1]
            parts["beat"] = cos_part
            if adc.iq:
                sin_part *= a * iq_imbalance[0]
                if aa is not None:
                    sin_part[aa[0]] *= aa[1]
                parts["beat_q"] = sin_part
            rk = rank[hs]
            dense = max_rank == 0 and nh == nc          # one hit in every segment (sorted): no scatter
            for c, part in parts.items():
                if dense:
                    acc[c] = part
                    continue
                acc[c] = np.zeros((nc, n), dtype=part.dtype)
                for r in range(max_rank + 1):
                    sel = np.nonzero(rk == r)[0]
                    if sel.size == 0:
                        continue
                    if r == 0:
                        acc[c][lseg[sel]] = part[sel]
                    else:
                        acc[c][lseg[sel]] += part[sel]
            del parts, cos_part, sin_part
        for c in channels:
            if c not in ("mzi", "mzi_q") and c not in acc:
                acc[c] = np.zeros((nc, n), dtype=np.float32 if fast else np.float64)
        if want_mzi:
            ub = u_inv[s0:s1]
            if phi is not None:
                mphi = mzi_det[0] + phi[:, n_pre:] if single_start else mzi_det[ub] + phi[:, n_pre:]
                mphi -= _delayed_noise(phi, np.arange(nc), n_pre, n, np.full(nc, m_mzi[0]),
                                       np.full(nc, w_mzi[0]), var_step, rng)
                mzi_v, mzi_s = _cos_sin(mphi, mzi_quadrature, fast)
                mzi_v *= mzi_amplitude_v
                acc["mzi"] = mzi_v
                if mzi_quadrature:       # the same MZI's 90-degree output: same phase noise, sin
                    acc["mzi_q"] = mzi_s * mzi_amplitude_v
            else:
                acc["mzi"] = np.repeat(mzi_clean, nc, axis=0) if single_start else mzi_clean[ub]
                if mzi_quadrature:
                    acc["mzi_q"] = np.repeat(mzi_clean_q, nc, axis=0) if single_start else mzi_clean_q[ub]

        for c in channels:
            v = acc[c]
            if c in ("mzi", "mzi_q"):
                if mzi_noise_asd_v_per_rthz > 0:
                    noise = standard_normal_f32(rng, (nc, n), mzi_noise_asd_v_per_rthz * math.sqrt(fs / 2.0))
                    v += noise
                    del noise
            else:
                if dc_v:
                    v += dc_v
                std = noise_std[s0:s1]
                if std.max(initial=0.0) > 0:
                    # float32 Box-Muller draws (gauss.py): 7 digits are plenty for a noise sample
                    if std.min() == std.max():          # one noise level for the chunk: no pass
                        noise = standard_normal_f32(rng, (nc, n), float(std[0]))
                    else:
                        noise = standard_normal_f32(rng, (nc, n))
                        noise *= std[:, None].astype(np.float32)
                    v += noise
                    del noise
            if volts is not None:
                volts[c][s0:s1] = v
            j = channels.index(c)
            if adc.quantize:
                v *= 1.0 / adc.lsb_v
                np.rint(v, out=v)
                lo, hi = adc.code_min, adc.code_max
            else:
                lo, hi = -adc.input_range_v / 2.0, adc.input_range_v / 2.0
            overrange[s0:s1, j] = (v.min(axis=1) < lo) | (v.max(axis=1) > hi)
            np.clip(v, lo, hi, out=v)
            outs[c][s0:s1] = v

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


__all__ = ["AdcSpec", "ChirpTrajectory", "HitBatch", "SynthError", "Synthesized", "sample_rate_for_range_hz",
           "synthesize", "trajectory", "trajectory_from_frequency"]
