"""I/Q imbalance of a coherent receiver: its model, its correction and its estimation.

A coherent receiver mixes the return with the local oscillator in a 90-degree optical hybrid and
detects the in-phase and quadrature outputs on two balanced photodiodes, digitized on two channels.
For a beat phase dPhi(t) the ideal outputs are I = A cos dPhi and Q = A sin dPhi, i.e. the complex
beat I + jQ = A exp(j dPhi): the sign of the beat frequency is measured, nothing folds (the
single-photodiode receiver sees |f| only). A real hybrid's quadrature is not exactly 90 degrees and the
two photodiode chains do not have exactly the same gain:

    I = A cos(dPhi),    Q = g A sin(dPhi + eps)

(g: gain ratio Q/I, eps: phase error). Then I + jQ = A [(1 + g e^{-j eps}) e^{j dPhi} + (1 - g e^{j eps})
e^{-j dPhi}] / 2 ... written with c = g e^{j eps}: I + jQ = A/2 [(1 + c*) e^{j dPhi} + (1 - c) e^{-j dPhi}],
so every tone has an IMAGE at the mirror frequency, (1 - c)/(1 + c*) in amplitude: the image-rejection
ratio IRR = |1 - c|^2 / |1 + c|^2 (0.5 dB and 5 deg: -25.6 dB). An image is a made-up return at the
opposite beat sign: on a triangle it pairs into a ghost with the wrong velocity.

Correction (Gram-Schmidt on the two channels): Q' = (Q / g - I sin eps) / cos eps = A sin dPhi, so
I + jQ' is the ideal complex beat.

Estimation from the data (:func:`estimate_imbalance`): for a tone of positive frequency f the
spectra of the two channels at +f are X_I = A/2 e^{j theta} W and X_Q = g A / (2j) e^{j(theta + eps)} W,
so j X_Q / X_I = g e^{j eps} = c, whatever the tone's amplitude, phase and window W. A tone of
negative frequency gives -conj(c) at +|f|; the two are told apart by the sign of the real part
(valid for |eps| < 90 deg). Every strong tone of a record (a target's beat: any target, static or
moving) is one estimate; they are combined by least squares (weights |X_I|^2, their SNR), with the
noise power of X_I's bins taken off the denominator (errors in the variable: without it the gain
comes out low by about 1 / SNR). A tone at SNR s gives c
with a relative error ~ 1/sqrt(s) per tone, so a few hundred tones at 30 dB pin g to ~1e-3 and eps to
~1 mrad: images then sit ~60 dB down, below the noise of any return.

Pure numpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import DTypeLike

from ..spectrum.window import DspInputError, get_window

#: a tone must stand this far above its record's median bin power to enter the estimate (30 dB)
MIN_TONE_SNR = 1e3
#: at least this many tones (segments x ramps) or the estimate is refused
MIN_TONES = 16


def image_rejection_db(gain: float, phase_rad: float) -> float:
    """Image-rejection ratio |1 - c|^2 / |1 + c|^2 in dB, c = gain e^{j phase} (-inf when ideal)."""
    c = gain * complex(math.cos(phase_rad), math.sin(phase_rad))
    num = abs(1.0 - c) ** 2
    return -math.inf if num == 0.0 else 10.0 * math.log10(num / abs(1.0 + c) ** 2)


def check_imbalance(gain: float, phase_rad: float) -> None:
    if not (math.isfinite(gain) and 0.1 <= gain <= 10.0):
        raise DspInputError(f"iq gain ratio {gain!r} must be finite and within [0.1, 10] (Q / I amplitude)")
    if not (math.isfinite(phase_rad) and abs(phase_rad) < math.radians(45.0)):
        raise DspInputError(f"iq phase error {phase_rad!r} rad must be finite and within +-45 degrees")


def correct(i: np.ndarray, q: np.ndarray, gain: float = 1.0, phase_rad: float = 0.0,
            out_dtype: DTypeLike = np.complex128) -> np.ndarray:
    """The complex beat I + jQ' with the imbalance removed (Q' = (Q / g - I sin eps) / cos eps)."""
    check_imbalance(gain, phase_rad)
    i = np.asarray(i)
    q = np.asarray(q)
    if i.shape != q.shape:
        raise DspInputError(f"I and Q records differ in shape: {i.shape} and {q.shape}")
    z = np.empty(i.shape, dtype=out_dtype)
    z.real = i
    if gain == 1.0 and phase_rad == 0.0:
        z.imag = q
        return z
    s, c = math.sin(phase_rad), math.cos(phase_rad)
    z.imag = q * (1.0 / (gain * c)) - i * (s / c)
    return z


@dataclass(frozen=True)
class ImbalanceFit:
    """The fitted gain ratio and phase error, their standard errors, and what they leave of an image."""

    gain: float
    phase_rad: float
    gain_sem: float
    phase_sem_rad: float
    tones: int
    irr_before_db: float        # image rejection of the uncorrected receiver (the fitted imbalance)
    irr_after_db: float         # what the fit's own uncertainty leaves after correction (1 sigma)

    def fitted(self) -> dict[str, Any]:
        return {"gain": self.gain, "phase_rad": self.phase_rad, "phase_deg": math.degrees(self.phase_rad)}

    def residuals(self) -> dict[str, Any]:
        return {"gain_sem": self.gain_sem, "phase_sem_rad": self.phase_sem_rad, "tones": self.tones,
                "image_rejection_before_db": self.irr_before_db, "image_rejection_after_db": self.irr_after_db}


def tone_ratios(i: np.ndarray, q: np.ndarray, *, window: str = "hann", min_bin: int = 4,
                min_snr: float = MIN_TONE_SNR) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per record (rows of ``i``, ``q``: (..., N) real), j X_Q / X_I at the strongest bin of I from
    ``min_bin`` up (DC and the window's lobe left out), folded onto c (see the module docstring), the
    weight |X_I|^2 and the record's mean noise power per bin (median / ln 2 of an exponential
    spectrum); only records whose tone stands ``min_snr`` above their median bin."""
    i = np.asarray(i, dtype=np.float64)
    q = np.asarray(q, dtype=np.float64)
    if i.shape != q.shape or i.ndim < 1 or i.shape[-1] < 4 * min_bin:
        raise DspInputError(f"I and Q must be records of the same shape (..., >= {4 * min_bin}), "
                            f"got {i.shape} and {q.shape}")
    n = i.shape[-1]
    w = get_window(window, n)
    xi = np.fft.rfft((i - i.mean(axis=-1, keepdims=True)) * w, axis=-1).reshape(-1, n // 2 + 1)
    xq = np.fft.rfft((q - q.mean(axis=-1, keepdims=True)) * w, axis=-1).reshape(-1, n // 2 + 1)
    p = np.abs(xi) ** 2
    k = min_bin + np.argmax(p[:, min_bin:], axis=-1)
    rows = np.arange(p.shape[0])
    peak = p[rows, k]
    med = np.median(p[:, min_bin:], axis=-1)
    strong = peak > min_snr * med
    r = 1j * xq[rows, k] / np.where(peak > 0, xi[rows, k], 1.0)
    r = np.where(r.real < 0, -np.conj(r), r)        # a negative-frequency tone gives -conj(c)
    return r[strong], peak[strong], med[strong] / math.log(2.0)


def estimate_imbalance(i: np.ndarray, q: np.ndarray, *, window: str = "hann",
                       min_tones: int = MIN_TONES) -> ImbalanceFit:
    """Gain ratio and phase error from records of I and Q (..., N) holding beat tones (module doc)."""
    r, wgt, noise = tone_ratios(i, q, window=window)
    if r.size < min_tones:
        raise DspInputError(f"I/Q imbalance: {r.size} records carry a tone 30 dB above their noise, at least "
                            f"{min_tones} are needed: point the receiver at a target (any surface within "
                            f"the range gate) and measure again")
    wn = wgt / wgt.sum()
    # least squares, sum j X_Q X_I* / sum |X_I|^2, with the denominator's noise power taken off: X_I's
    # own noise inflates |X_I|^2 by the bin's noise power and would pull the gain low by 1 / SNR
    c = complex(np.sum(wgt * r) / (wgt.sum() - noise.sum()))
    gain, phase = abs(c), math.atan2(c.imag, c.real)
    check_imbalance(gain, phase)
    # scatter of the single tones about the weighted mean -> standard error of the mean
    n_eff = 1.0 / float(np.sum(wn ** 2))
    rel = r / c
    g_sd = float(np.sqrt(np.sum(wn * (np.abs(rel) - 1.0) ** 2))) * gain
    p_sd = float(np.sqrt(np.sum(wn * np.angle(rel) ** 2)))
    g_sem, p_sem = g_sd / math.sqrt(n_eff), p_sd / math.sqrt(n_eff)
    # after correction by (gain, phase) the true c differs by ~(g_sem / gain, p_sem): its image
    after = image_rejection_db(1.0 + g_sem / gain, p_sem)
    return ImbalanceFit(gain, phase, g_sem, p_sem, int(r.size), image_rejection_db(gain, phase), after)


def ramp_volts(seg: np.ndarray, lsb_v: float, *, iq: bool, down: bool, out: np.ndarray | None = None) -> np.ndarray:
    """One ramp's samples as the DSP takes them: float64 volts of a real beat; for an I/Q beat (the
    corrected complex I + jQ) complex volts, a down ramp conjugated so that it puts a static target at
    the up ramp's +f_R (the sign convention of lidard.dsp.ranging.velocity). ``out``: a real beat's
    volts are written there (a float64 array of ``seg``'s shape: a caller's scratch buffer)."""
    if not iq:      # cast, then scale in place: the same values as one mixed-type multiply, ~25 % faster
        if out is None:
            volts = seg.astype(np.float64)
        else:
            volts = out
            np.copyto(volts, seg)
        volts *= lsb_v
        return volts
    z = seg * lsb_v
    return np.conjugate(z, out=z) if down else z


#: a detection at the mirror frequency of a stronger one, at most this far below it, is taken as its
#: image and dropped: -15 dB leaves room for an uncalibrated hybrid (0.5 dB, 5 deg: -25.6 dB) and is
#: far above a calibrated one's residual (below -60 dB), so a real second return is lost only if it
#: sits within a bin of the exact mirror of one 30 times stronger
IMAGE_RATIO_DB = -15.0


def mirror_images(index: np.ndarray, power: np.ndarray, valid: np.ndarray, n_fft: int,
                  ratio_db: float = IMAGE_RATIO_DB, tol_bins: int = 1) -> np.ndarray:
    """(batch..., K) detections of a two-sided, fft-shifted spectrum (``index``: spectrum indices,
    ``power`` their powers) that sit within ``tol_bins`` of the mirror of a detection at least
    ``-ratio_db`` dB stronger: the receiver's image of that return, not a return."""
    b = np.asarray(index, dtype=np.int64) - n_fft // 2                  # signed bins
    p = np.asarray(power, dtype=np.float64)
    v = np.asarray(valid, dtype=bool)
    mirror = np.abs(b[..., :, None] + b[..., None, :]) <= tol_bins      # [i, j]: b_i ~ -b_j
    weaker = p[..., :, None] <= 10.0 ** (ratio_db / 10.0) * p[..., None, :]
    return v & (mirror & weaker & v[..., None, :]).any(axis=-1)
