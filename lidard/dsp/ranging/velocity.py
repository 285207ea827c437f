"""Range and radial velocity from up- and down-ramp beat frequencies (dissertation §2.1.2,
eqs. 2-4..2-8).

The dissertation writes, for a target at distance d APPROACHING at speed V,
    f_up = 2 gamma d / c - 2 V / lambda       (2-4)
    f_down = 2 gamma d / c + 2 V / lambda     (2-5)
so d = c (f_up + f_down) / (4 gamma) (2-6) and V = lambda (f_down - f_up) / 4 (2-7).
lidard reports radial velocity POSITIVE WHEN RECEDING (v_radial = -V), hence
    v_radial = lambda (f_up - f_down) / 4.

Real (single-photodiode) beats are observed as |f|.  When the Doppler shift exceeds the range
beat, one beat folds through zero and the observed pair (f_R - f_D folded, f_R + f_D) is the same
as that of a target with range-beat and Doppler swapped: the data cannot tell them apart.  Such
points are marked invalid instead of reported with a wrong range:
* any beat closer to DC than ``min_beat_hz`` (the folded beat sits on DC and its own image), and
* with ``max_speed_mps`` given, any pair whose swapped interpretation is physically possible,
  i.e. whose range beat (f_up + f_down)/2 is not above the largest Doppler 2 v_max / lambda, and
  any pair whose Doppler exceeds 2 v_max / lambda.
With I/Q data (``iq=True``) beat signs are measured, nothing folds, and d, v follow from the signed
frequencies.  Sign convention for I/Q input: pass both beats in the dissertation's convention
(a stationary target gives POSITIVE f_up and f_down), i.e. the down-ramp spectrum conjugated.

Pairing with several returns per ramp: every (up, down) pair within the speed limit is a hypothesis,
scored by its likelihood (the lines' noise-normalised powers with one amplitude,
:mod:`lidard.dsp.ranging.assign`), and the set of pairs with the largest total likelihood is taken;
among equally likely sets, the one needing the least motion.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import DTypeLike

from lidard.dsp.spectrum.rangefft import C_M_PER_S
from lidard.dsp.ranging.assign import best_matching, pair_loglik, tie_llr
from lidard.dsp.spectrum.window import DspInputError


def _as_2d(a: object, name: str, dtype: DTypeLike) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim == 0:
        raise DspInputError(f"{name} must have shape (..., K), got a scalar")
    return arr.astype(dtype, copy=False)


def pair_up_down(*args: Any, **kwargs: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair up/down-ramp peaks and solve eqs. 2-6/2-7: (range_m, velocity_mps, valid) of
    :func:`pair_up_down_matched` (its arguments)."""
    rng, vel, ok, _ = pair_up_down_matched(*args, **kwargs)
    return rng, vel, ok


def pair_up_down_matched(
    f_up_hz: object,
    f_down_hz: object,
    valid_up: object,
    valid_down: object,
    chirp_rate_hz_per_s: float,
    wavelength_m: float,
    iq: bool = False,
    *,
    max_speed_mps: float | None = None,
    min_beat_hz: float = 0.0,
    snr: tuple[object, object] | None = None,
    records: int = 1,
    tie_level: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pair up/down-ramp peaks and solve eqs. 2-6/2-7 (velocity positive when receding).

    f_up_hz, f_down_hz: (..., K) beat frequencies (real: magnitudes; iq: signed, see module doc).
    valid_up, valid_down: (..., K) masks of which entries are detections.
    Returns range_m, velocity_mps, valid, each (..., K) aligned with the UP-ramp detections (range
    and velocity are 0.0 where ``valid`` is False), and the down slot paired with each (-1: none; a
    pair may be paired but not valid: folding, beats at DC).
    ``snr``: (up, down) noise-normalised peak powers (..., K), each the mean of ``records`` records: the
    pairs' likelihoods (:func:`lidard.dsp.ranging.assign.pair_loglik`); without them every pair is
    equally likely and the least motion decides. ``tie_level``: the level at which two sets of pairs
    are equally good fits (:func:`lidard.dsp.ranging.assign.tie_llr`).
    """
    fu = _as_2d(f_up_hz, "f_up_hz", np.float64)
    fd = _as_2d(f_down_hz, "f_down_hz", np.float64)
    vu = _as_2d(valid_up, "valid_up", bool)
    vd = _as_2d(valid_down, "valid_down", bool)
    if fu.shape != vu.shape or fd.shape != vd.shape or fu.shape[:-1] != fd.shape[:-1]:
        raise DspInputError(
            f"shape mismatch: f_up {fu.shape}, valid_up {vu.shape}, f_down {fd.shape}, valid_down {vd.shape}"
        )
    if not (np.isfinite(chirp_rate_hz_per_s) and chirp_rate_hz_per_s > 0):
        raise DspInputError(f"chirp_rate_hz_per_s={chirp_rate_hz_per_s!r} must be positive")
    if not (np.isfinite(wavelength_m) and wavelength_m > 0):
        raise DspInputError(f"wavelength_m={wavelength_m!r} must be positive")
    if max_speed_mps is not None and not max_speed_mps > 0:
        raise DspInputError(f"max_speed_mps={max_speed_mps!r} must be positive or None")
    if np.any(vu & ~np.isfinite(fu)) or np.any(vd & ~np.isfinite(fd)):
        raise DspInputError("a beat frequency marked valid is NaN or infinite")

    lead = fu.shape[:-1]
    ku, kd = fu.shape[-1], fd.shape[-1]
    fu2 = np.where(vu, fu, 0.0).reshape(-1, ku)
    fd2 = np.where(vd, fd, 0.0).reshape(-1, kd)
    vu2, vd2 = vu.reshape(-1, ku), vd.reshape(-1, kd)
    if not iq:
        fu2, fd2 = np.abs(fu2), np.abs(fd2)
    f_dmax = np.inf if max_speed_mps is None else 2.0 * max_speed_mps / wavelength_m

    if snr is not None:
        loglik = pair_loglik(np.asarray(snr[0]).reshape(-1, ku), np.asarray(snr[1]).reshape(-1, kd), records)
    else:
        loglik = np.ones((fu2.shape[0], ku, kd))
    # a hypothesis: both lines detected, its Doppler (half the beats' disagreement) within the limit
    motion = np.abs(fd2[:, None, :] - fu2[:, :, None])
    allowed = vu2[:, :, None] & vd2[:, None, :] & (motion <= 2.0 * f_dmax)
    match = best_matching(np.where(allowed, loglik, -np.inf), motion, tie_llr(tie_level))
    paired = match >= 0
    fdn = np.take_along_axis(fd2, np.maximum(match, 0), axis=-1)
    f_range = 0.5 * (fu2 + fdn)  # 2 gamma d / c
    f_dopp = 0.5 * (fdn - fu2)  # 2 V / lambda, V approaching (eq. 2-7)
    range_m = C_M_PER_S * f_range / (2.0 * chirp_rate_hz_per_s)
    velocity_mps = -wavelength_m * f_dopp / 2.0  # receding positive

    valid = paired & (range_m >= 0) & (np.abs(f_dopp) <= f_dmax)
    if not iq:
        beats_ok = (fu2 >= min_beat_hz) & (fdn >= min_beat_hz)
        # Swapped interpretation (range beat <-> Doppler) possible -> ambiguous.
        unambiguous = f_range > f_dmax if max_speed_mps is not None else np.ones_like(valid)
        valid &= beats_ok & unambiguous
    # Invalid slots hold 0.0 (not NaN) so downstream arithmetic never propagates NaN; use `valid`.
    range_m = np.where(valid, range_m, 0.0)
    velocity_mps = np.where(valid, velocity_mps, 0.0)
    shape = lead + (ku,)
    return range_m.reshape(shape), velocity_mps.reshape(shape), valid.reshape(shape), match.reshape(shape)
