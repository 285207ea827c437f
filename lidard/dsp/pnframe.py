"""Batched laser phase-noise compensation in the scan DSP (dissertation §2.3, Fig. 2-6, Fig. 2-7).

:mod:`lidard.dsp.phasenoise.compensate` compensates one record; this module does the same for a whole batch of
pixels x averages x ramps at once, and feeds the result to the frame DSP's detection chain:

1. per ramp (up and down separately: the MZI beat passes through zero at the turning points) the
   monitor-MZI beat is complex-demodulated at its *nominal* beat ``gamma tau_m`` and low-passed
   (:func:`mzi_phase_noise_batch`, the batched form of :func:`lidard.dsp.phasenoise.compensate.mzi_phase_noise` with a known
   beat): ``delta(t)`` = phase noise + residual chirp nonlinearity seen through the delay tau_m;
2. the cumulative sums ``S_M(t) = sum_{m<M} delta(t - m tau_m)`` for M = 0..M_max are built once
   (M_max = ceil(max round trip / tau_m));
3. the analytic LiDAR beat of the analysed window is multiplied by ``exp(-j S_M)`` for every M and
   Fourier transformed; every range bin takes its value from its nearest M (bin frequency / (gamma
   tau_m), rounded): the *composite spectrum*, on the same grid and with the same scale as the
   plain :class:`lidard.dsp.frame.FrameDsp` spectrum (a real cosine of amplitude A puts A/2 in its bin);
4. OS-CFAR runs on the composite power averaged over the averages, and the sub-bin estimator runs
   on the real compensated ramp ``Re(z exp(-j S_M))`` of the M of each detection (the estimator's
   time-domain path, so ``newton`` still models the negative-frequency image), then the usual
   up/down pairing.

Why the nominal beat and not a measured one: the mean frequency of one ramp's MZI beat includes the
realised mean of the laser's frequency noise, which belongs to ``delta``; removing it would shift
every compensated peak by M times that mean (tens of bins for a 3 MHz linewidth). With the nominal
beat the compensation also maps a chirp slope error onto the nominal slope at tau = M tau_m, which
is what the ranging (nominal gamma) assumes anyway; a scan without linearization (a slope several
per cent off) therefore gets range jumps at the M boundaries: compensate linearized chirps.

Pure numpy/scipy (no per-pixel Python loops: loops run over M and over the two ramps only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from .chain import detect_and_refine
from .detect.cfar import CfarSettings
from .ranging.iqbalance import mirror_images, ramp_volts
from .spectrum.instfreq import check_positive, hilbert
from .phasenoise.compensate import demodulated_phase
from .phasenoise.reconstruct import delayed, quadrature_delta, reconstruct_phase, whole_delay_samples
from .spectrum.rangefft import C_M_PER_S, RangeFFT, windowed_fft
from .spectrum.window import DspInputError, WindowName, get_window


def mzi_phase_noise_batch(mzi: np.ndarray, *, fs_hz: float, edge_s: float, beat_hz: float,
                          bandwidth_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``delta`` (rad, float64, shape of ``mzi``) and the valid-sample mask (last axis) of ramps of MZI beat.

    Batched over leading axes; one ramp per row on the last axis. Same algorithm as
    :func:`lidard.dsp.phasenoise.compensate.mzi_phase_noise` with ``beat_hz`` given: remove the mean, mix down by
    ``beat_hz``, Gaussian low-pass (-3 dB at ``bandwidth_hz``, default beat/2) as a complex signal,
    angle about its circular mean, unwrapped; samples within ``edge_s`` of either end are zero.
    """
    x = np.asarray(mzi, dtype=np.float64)
    if x.ndim < 1 or x.shape[-1] == 0:
        raise DspInputError(f"mzi: expected ramps on the last axis, got shape {x.shape}")
    if not np.all(np.isfinite(x)):
        raise DspInputError("mzi: contains NaN or inf")
    fs_hz = check_positive("fs_hz", fs_hz)
    beat_hz = check_positive("beat_hz", beat_hz)
    if beat_hz >= fs_hz / 2:
        raise DspInputError(f"beat_hz={beat_hz!r}: the MZI beat is above Nyquist at fs_hz={fs_hz!r}")
    bandwidth_hz = check_positive("bandwidth_hz", 0.5 * beat_hz if bandwidth_hz is None else bandwidth_hz)
    n = x.shape[-1]
    n_edge = int(math.ceil(edge_s * fs_hz))
    if 2 * n_edge + 16 > n:
        raise DspInputError(f"mzi: {n} samples per ramp are too few for edge_s={edge_s!r} at fs_hz={fs_hz!r}")
    valid = np.zeros(n, dtype=bool)
    valid[n_edge:n - n_edge] = True
    delta = demodulated_phase(x - x.mean(axis=-1, keepdims=True), fs_hz=fs_hz, beat_hz=beat_hz,
                              bandwidth_hz=bandwidth_hz, valid=valid)
    return delta, valid


class FrameGeometry(Protocol):
    """What this front end reads of a :class:`lidard.dsp.frame.FrameDsp` (frame builds on this module,
    not the reverse: no import cycle)."""

    # read-only (FrameDsp is frozen; some are its properties)
    @property
    def ramp_samples(self) -> int: ...
    @property
    def fs_hz(self) -> float: ...
    @property
    def chirp_rate_hz_per_s(self) -> float: ...
    @property
    def wavelength_m(self) -> float: ...
    @property
    def max_range_m(self) -> float: ...
    @property
    def max_speed_mps(self) -> float: ...
    @property
    def window(self) -> WindowName: ...
    @property
    def pfa(self) -> float: ...
    @property
    def ramp_pfa(self) -> float: ...
    @property
    def max_returns(self) -> int: ...
    @property
    def candidate_slots(self) -> int: ...
    @property
    def estimator(self) -> str: ...
    @property
    def iq(self) -> bool: ...
    @property
    def offset(self) -> int: ...
    @property
    def n_used(self) -> int: ...
    @property
    def rfft(self) -> RangeFFT: ...
    @property
    def bin_range(self) -> tuple[int, int]: ...
    @property
    def cfar(self) -> CfarSettings: ...

@dataclass(frozen=True)
class PhaseNoiseCompensator:
    """Geometry of the compensation: monitor delay, deepest M, known chirp rate, ADC rate.

    ``max_delay_s``: the largest round trip to compensate (2 max_range / c); M runs 0..ceil(max/tau_m).
    ``edge_s``: samples at each end of a ramp whose MZI phase is not trusted (filter transients);
    default max(20 samples, 1 us) as in :func:`lidard.dsp.phasenoise.compensate.compensated_spectrum`.
    """

    fs_hz: float
    mzi_delay_s: float
    max_delay_s: float
    chirp_rate_hz_per_s: float
    edge_s: float | None = None
    bandwidth_hz: float | None = None
    tau_step_s: float | None = None      # quadrature monitor: round-trip grid of the compensation

    def __post_init__(self) -> None:
        for name in ("fs_hz", "mzi_delay_s", "max_delay_s", "chirp_rate_hz_per_s"):
            check_positive(name, getattr(self, name))
        if self.tau_step_s is not None:
            check_positive("tau_step_s", self.tau_step_s)
        if self.edge_s is not None and not (math.isfinite(self.edge_s) and self.edge_s >= 0):
            raise DspInputError(f"edge_s={self.edge_s!r} must be >= 0")

    @property
    def step_s(self) -> float:
        """Round-trip grid with a rebuilt laser phase: tau_m / 16 unless given (the phase residual over
        half a step, 2 pi linewidth step / 2, is 0.2 rad^2 at tau_c = 0.1 us)."""
        return self.mzi_delay_s / 16 if self.tau_step_s is None else float(self.tau_step_s)

    @property
    def m_max(self) -> int:
        return int(math.ceil(self.max_delay_s / self.mzi_delay_s - 1e-9))

    @property
    def mzi_beat_hz(self) -> float:
        return self.chirp_rate_hz_per_s * self.mzi_delay_s

    @property
    def delay_samples(self) -> float:
        return self.mzi_delay_s * self.fs_hz

    @property
    def edge_seconds(self) -> float:
        return max(20.0 / self.fs_hz, 1e-6) if self.edge_s is None else float(self.edge_s)

    @property
    def edge_samples(self) -> int:
        return int(math.ceil(self.edge_seconds * self.fs_hz))

    @property
    def min_start(self) -> int:
        """First sample of a ramp an analysis window may start at (all delayed MZI history exists)."""
        return self.edge_samples + int(math.ceil(self.m_max * self.delay_samples))

    def m_of_freq(self, freq_hz: np.ndarray) -> np.ndarray:
        """Nearest M for beat frequencies (the target round trip is f / gamma)."""
        return np.clip(np.rint(np.asarray(freq_hz) / self.mzi_beat_hz), 0, self.m_max).astype(np.int64)

    def prepare(self, beat: np.ndarray, mzi: np.ndarray, start: int, n: int,
                mzi_q: np.ndarray | None = None) -> CompensatedRamps:
        """Analytic beat and the compensation phases of the window [start, start + n) of every ramp.

        ``beat``, ``mzi``: (..., ramp_samples) real, sample-aligned (same trigger, same record). A
        complex ``beat`` is an I/Q receiver's (already analytic: no Hilbert transform; a conjugated down
        ramp carries the negated phase noise, as the down ramp's demodulated MZI does).
        ``mzi_q``: the quadrature output of the same MZI (a second monitor channel): the laser phase is
        rebuilt per sample (:mod:`lidard.dsp.phasenoise.reconstruct`) and every bin is compensated at its own round
        trip (to ``tau_step_s``) instead of the nearest multiple of tau_m.
        """
        b = np.asarray(beat)
        b = b.astype(np.complex128 if np.iscomplexobj(b) else np.float64, copy=False)
        m = np.asarray(mzi, dtype=np.float64)
        if b.shape != m.shape:
            raise DspInputError(f"beat and mzi must have the same shape, got {b.shape} and {m.shape}")
        r = b.shape[-1]
        stop = r - self.edge_samples
        if start < self.min_start or start + n > stop or n < 16:
            raise DspInputError(
                f"analysis window [{start}, {start + n}) of a {r}-sample ramp does not fit the phase-noise "
                f"compensation: it needs start >= {self.min_start} (M up to {self.m_max} x {self.mzi_delay_s * 1e9:.0f} ns "
                f"+ edge) and end <= {stop}; lower max_range_m or raise use_fraction's margin")
        if not np.all(np.isfinite(b)):
            raise DspInputError("beat contains NaN or inf")
        if np.iscomplexobj(b):
            z = (b - b.mean(axis=-1, keepdims=True))[..., start:start + n]
        else:
            z = hilbert(b - b.mean(axis=-1, keepdims=True), axis=-1)[..., start:start + n]
        if mzi_q is not None:
            if np.shape(mzi_q) != b.shape:
                raise DspInputError(f"mzi_q must have the beat's shape {b.shape}, got {np.shape(mzi_q)}")
            delta = quadrature_delta(m, mzi_q, fs_hz=self.fs_hz, beat_hz=self.mzi_beat_hz)
            valid = np.zeros(r, dtype=bool)
            valid[self.edge_samples:stop] = True
            phi, _ = reconstruct_phase(delta, valid, whole_delay_samples(self.mzi_delay_s, self.fs_hz))
            return CompensatedRamps(z=z, s=None, comp=self, phi=phi, start=start, iq=np.iscomplexobj(b))
        delta, _ = mzi_phase_noise_batch(m, fs_hz=self.fs_hz, edge_s=self.edge_seconds,
                                         beat_hz=self.mzi_beat_hz, bandwidth_hz=self.bandwidth_hz)
        d = self.delay_samples
        s = np.empty((self.m_max + 1,) + b.shape[:-1] + (n,))
        acc = np.zeros_like(delta)
        s[0] = 0.0
        for mm in range(self.m_max):
            acc += delayed(delta, mm * d)
            s[mm + 1] = acc[..., start:start + n]
        return CompensatedRamps(z=z, s=s, comp=self, iq=np.iscomplexobj(b))


@dataclass(frozen=True)
class CompensatedRamps:
    """Analytic beat ``z`` (..., n) of one ramp window and its compensation phases: either the
    cumulative MZI phases ``s`` (M_max + 1, ..., n) (one real monitor: index M = round trip / tau_m) or
    the rebuilt laser phase ``phi`` (..., ramp) (quadrature monitor: index g = round trip / tau_step_s)."""

    z: np.ndarray
    s: np.ndarray | None
    comp: PhaseNoiseCompensator
    phi: np.ndarray | None = None
    start: int = 0
    iq: bool = False            # ``z`` is an I/Q receiver's complex beat: two-sided spectra, complex signals

    @property
    def unit_s(self) -> float:
        """Round trip per index step: tau_m, or tau_step_s with a rebuilt phase."""
        return self.comp.mzi_delay_s if self.phi is None else self.comp.step_s

    def index_of_freq(self, freq_hz: np.ndarray) -> np.ndarray:
        if self.phi is None:
            return self.comp.m_of_freq(freq_hz)
        g_max = int(math.ceil(self.comp.max_delay_s / self.comp.step_s - 1e-9))
        return np.clip(np.rint(np.asarray(freq_hz) / (self.comp.chirp_rate_hz_per_s * self.comp.step_s)),
                       0, g_max).astype(np.int64)

    def phase(self, g: int) -> np.ndarray:
        """The compensation phase (..., n) for index ``g``."""
        if self.phi is None:
            assert self.s is not None   # one of the two is given (class doc)
            return self.s[g]
        n = self.z.shape[-1]
        win = slice(self.start, self.start + n)
        return self.phi[..., win] - delayed(self.phi, g * self.comp.step_s * self.comp.fs_hz)[..., win]

    def composite_spectrum(self, window: np.ndarray, n_fft: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(spectrum (..., n_fft // 2 + 1) complex, index of each bin (n_fft // 2 + 1,): M or g).

        Scale as :class:`RangeFFT` for a real ramp: FFT(z e^{-j S} w) / (2 sum w), so that the
        compensated spectrum of a zero-linewidth beat matches the plain one. I/Q (``iq``): the two-sided,
        fft-shifted spectrum (n_fft,) scaled FFT / sum w as RangeFFT's, each bin at the M of its |f|.
        """
        n = self.z.shape[-1]
        n_fft = int(n_fft or n)
        if self.iq:
            freq = (np.arange(n_fft) - n_fft // 2) * (self.comp.fs_hz / n_fft)
            layout, scale = "shifted", 1.0 / np.sum(window)
        else:
            # fftfreq's arithmetic, so that ties (bins exactly half-way between two M) break as in compensate
            freq = np.arange(n_fft // 2 + 1) * (1.0 / (n_fft * (1.0 / self.comp.fs_hz)))
            layout, scale = "analytic", 1.0 / (2.0 * np.sum(window))
        m_of_bin = self.index_of_freq(np.abs(freq))
        out = np.empty(self.z.shape[:-1] + (freq.size,), dtype=np.complex128)
        for mm in np.unique(m_of_bin):
            sel = m_of_bin == mm
            y = self.z if mm == 0 else self.z * np.exp(-1j * self.phase(mm))
            out[..., sel] = windowed_fft(y, window, n_fft, layout)[..., sel]
        out *= scale
        return out, m_of_bin

    def real_signals(self, m_idx: np.ndarray) -> np.ndarray:
        """Re(z exp(-j S)) for each index in ``m_idx`` (..., K): shape (..., K, n); for an I/Q beat
        the complex z exp(-j S) itself (the estimator's complex path)."""
        m_idx = np.asarray(m_idx, dtype=np.int64)
        lead = self.z.shape[:-1]
        if m_idx.shape[:-1] != lead:
            raise DspInputError(f"m_idx shape {m_idx.shape} does not match the ramps {lead} + (K,)")
        out = np.empty(m_idx.shape + self.z.shape[-1:], dtype=np.complex128 if self.iq else np.float64)
        for g in np.unique(m_idx):
            sel = m_idx == g                               # (..., K)
            lead_sel = np.nonzero(sel)
            y = self.z * np.exp(-1j * self.phase(int(g)))      # (..., n)
            out[lead_sel] = (y if self.iq else y.real)[lead_sel[:-1]]
        return out


@dataclass(frozen=True)
class CompensatedFrameInfo:
    m_max: int
    m_min_used: int          # smallest M that a bin inside the range gate uses
    m_max_used: int          # largest M that a bin inside the range gate uses
    mzi_beat_hz: float


def compensator_for(dsp: FrameGeometry, mzi_delay_s: float) -> PhaseNoiseCompensator:
    """The compensator a frame DSP needs: every range up to its gate (plus Doppler) gets its nearest M."""
    doppler = 2 * dsp.max_speed_mps / dsp.wavelength_m
    max_delay = (2 * dsp.max_range_m / C_M_PER_S) + doppler / dsp.chirp_rate_hz_per_s
    return PhaseNoiseCompensator(fs_hz=dsp.fs_hz, mzi_delay_s=mzi_delay_s, max_delay_s=max_delay,
                                 chirp_rate_hz_per_s=dsp.chirp_rate_hz_per_s)


def gate_m_range(dsp: FrameGeometry, mzi_delay_s: float) -> tuple[int, int]:
    """Smallest and largest nearest-M over the bins a frame DSP searches (its gate plus Doppler)."""
    comp = compensator_for(dsp, mzi_delay_s)
    lo, hi = dsp.bin_range
    m = comp.m_of_freq(np.arange(lo, hi + 1) * dsp.rfft.delta_f)
    return int(m.min()), int(m.max())


def compensated_front_end(dsp: FrameGeometry, beat: np.ndarray, mzi: np.ndarray, lsb_v: float = 1.0, *,
                          mzi_delay_s: float, mzi_lsb_v: float = 1.0,
                          comp: PhaseNoiseCompensator | None = None,
                          mzi_q: np.ndarray | None = None) -> tuple[list[Any], list[Any]]:
    """Per ramp (up, down): refined beat frequencies (n_pix, K) and CFAR detections of the composite
    compensated spectrum; :meth:`FrameDsp.process` pairs them as it pairs its own.

    ``beat``, ``mzi`` (and ``mzi_q``, the quadrature monitor, same LSB as ``mzi``): (n_pix, averages,
    >= 2 * ramp_samples), the same segments (same trigger).
    """
    x = np.asarray(beat)
    mz = np.asarray(mzi)
    if x.ndim != 3 or x.shape[-1] < 2 * dsp.ramp_samples:
        raise DspInputError(f"beat must be (n_pix, averages, >= {2 * dsp.ramp_samples}), got {x.shape}")
    if mz.shape != x.shape:
        raise DspInputError(f"mzi must have the beat's shape {x.shape}, got {mz.shape}")
    if mzi_q is not None and np.shape(mzi_q) != x.shape:
        raise DspInputError(f"mzi_q must have the beat's shape {x.shape}, got {np.shape(mzi_q)}")
    comp = comp or compensator_for(dsp, mzi_delay_s)
    a, n, r = dsp.offset, dsp.n_used, dsp.ramp_samples
    rf = dsp.rfft
    w = get_window(dsp.window, n)
    out_f, out_det = [], []
    for r0 in (0, r):
        q = None if mzi_q is None else np.asarray(mzi_q)[..., r0:r0 + r].astype(np.float64) * mzi_lsb_v
        b = ramp_volts(x[..., r0:r0 + r], lsb_v, iq=dsp.iq, down=bool(r0))
        # the conjugated down ramp carries -(phase noise), and so does the down ramp's demodulated MZI
        # (its fringe runs at -gamma tau_m): the compensation is applied as to the up ramp
        ramps = comp.prepare(b, mz[..., r0:r0 + r].astype(np.float64) * mzi_lsb_v, a, n, mzi_q=q)
        spec, m_of_bin = ramps.composite_spectrum(w, rf.n_fft)
        # the estimator refines each detection on the compensated ramp of its own delay (real: its
        # time-domain path, so ``newton`` still models the negative-frequency image; I/Q: complex)
        def signals(idx: np.ndarray, ramps: CompensatedRamps = ramps,
                    m_of_bin: np.ndarray = m_of_bin) -> tuple[np.ndarray, np.ndarray, None]:
            return ramps.real_signals(m_of_bin[idx]), rf.index_to_bin(idx), None

        res = detect_and_refine(
            spec, signals, cfar=dsp.cfar,
            estimator=dsp.estimator, average_axis=1, idle_index=int(rf.bin_to_index(1)))
        det = res.detections
        if dsp.iq:      # the hybrid's image of a stronger return is not a return
            det = replace(det, valid=det.valid & ~mirror_images(det.index, det.power, det.valid, rf.n_fft))
        # "unresolved" here stays the detector's -6 dB width test, not the model-order test of the plain
        # spectrum (lidard.dsp.ranging.order): after compensation a clean return keeps a residual phase
        # noise proportional to its amplitude, and the tone model leaves 0.5-1.1 % of its energy in the
        # cells (0.3 % on the plain spectrum): the order test flagged 14 of 80 clean ramps at a 3.2 MHz
        # linewidth (its stated level: 0.1 %), on the composite spectrum and on each peak's own delay alike
        out_f.append(res.frac_bins * rf.delta_f)
        out_det.append(det)
    return out_f, out_det


class _FrameProcess(FrameGeometry, Protocol):
    """A frame DSP that also processes (lidard.dsp.frame.FrameDsp)."""

    def process(self, beat: np.ndarray, lsb_v: float = ..., *, mzi: np.ndarray | None = ...,
                mzi_delay_s: float | None = ..., mzi_lsb_v: float = ...) -> Any: ...


def process_compensated(dsp: _FrameProcess, beat: np.ndarray, mzi: np.ndarray, lsb_v: float = 1.0, *,
                        mzi_delay_s: float, mzi_lsb_v: float = 1.0) -> tuple[Any, CompensatedFrameInfo]:
    """``dsp.process(beat, lsb_v, mzi=mzi, ...)`` (a FrameResult) and which M the gate used
    (a :class:`CompensatedFrameInfo`)."""
    res = dsp.process(beat, lsb_v, mzi=mzi, mzi_delay_s=mzi_delay_s, mzi_lsb_v=mzi_lsb_v)
    comp = compensator_for(dsp, mzi_delay_s)
    m_lo, m_hi = gate_m_range(dsp, mzi_delay_s)
    return res, CompensatedFrameInfo(m_max=comp.m_max, m_min_used=m_lo, m_max_used=m_hi,
                                     mzi_beat_hz=comp.mzi_beat_hz)
