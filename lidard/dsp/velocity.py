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

Pairing with several returns per ramp: candidate pairs are ranked by |f_down - f_up| (the pair
whose single-ramp ranges agree best) and matched greedily, strongest agreement first; pairs whose
Doppler would exceed the speed limit are never matched.
"""

from __future__ import annotations

import numpy as np

from lidard.dsp.rangefft import C_M_PER_S
from lidard.dsp.window import DspInputError


def _as_2d(a: object, name: str, dtype) -> np.ndarray:
    arr = np.asarray(a)
    if arr.ndim == 0:
        raise DspInputError(f"{name} must have shape (..., K), got a scalar")
    return arr.astype(dtype, copy=False)


def pair_up_down(
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
    strength: tuple[object, object] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pair up/down-ramp peaks and solve eqs. 2-6/2-7 (velocity positive when receding).

    f_up_hz, f_down_hz: (..., K) beat frequencies (real: magnitudes; iq: signed, see module doc).
    valid_up, valid_down: (..., K) masks of which entries are detections.
    Returns range_m, velocity_mps, valid, each (..., K) aligned with the UP-ramp detections;
    range and velocity are 0.0 where ``valid`` is False.
    ``strength``: (up, down) peak powers (..., K): pairs are then matched strongest first (the weaker
    peak of the pair decides) instead of smallest Doppler first -- for a wide Doppler band without a
    prior (I/Q), where "smallest Doppler" would prefer a noise peak near a return's mirror beat.
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

    if strength is not None:
        su = np.asarray(strength[0], dtype=np.float64).reshape(-1, ku)
        sd = np.asarray(strength[1], dtype=np.float64).reshape(-1, kd)
        rank = -np.minimum(su[:, :, None], sd[:, None, :])
    else:
        rank = None
    match = _greedy_match(fu2, fd2, vu2, vd2, f_dmax, rank)
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
    return range_m.reshape(lead + (ku,)), velocity_mps.reshape(lead + (ku,)), valid.reshape(lead + (ku,))


def _greedy_match(fu2, fd2, vu2, vd2, f_dmax, rank=None) -> np.ndarray:
    """Per row, the down-ramp peak paired with each up-ramp peak (-1: none), cheapest pair first
    (``rank`` [row, i, j]: the order to take allowed pairs in; default their Doppler)."""
    ku, kd = fu2.shape[-1], fd2.shape[-1]
    # Pair cost: disagreement of the two single-ramp beats = 2 |Doppler|.
    cost = np.abs(fd2[:, None, :] - fu2[:, :, None])  # [row, up i, down j]
    ok = vu2[:, :, None] & vd2[:, None, :] & (cost <= 2.0 * f_dmax)
    cost = np.where(ok, cost if rank is None else rank, np.inf)
    match = np.full(fu2.shape, -1, dtype=np.int64)
    rows = np.arange(fu2.shape[0])
    for _ in range(min(ku, kd)):
        flat = np.argmin(cost.reshape(cost.shape[0], ku * kd), axis=-1)
        i, j = np.divmod(flat, kd)
        good = np.isfinite(cost[rows, i, j])
        match[rows[good], i[good]] = j[good]
        cost[rows[good], i[good], :] = np.inf
        cost[rows[good], :, j[good]] = np.inf
    return match
