"""How far a drive's chirp is from the ideal linear chirp: the linearization health check's measure
(dissertation §2.2, Fig. 2-3/2-4).

One measurement of the ILC (:mod:`lidard.dsp.linearize._measure`), without learning: the monitor-MZI records
of the drive in use are demodulated into the drive-frame optical frequency, and each ramp is compared
with the ideal chirp the ILC learns towards (slope ``excursion_hz / ramp_s``, free offset) over the
region of interest. The RMS of that error is what the ILC drives down, so a freshly linearized drive
shows the ILC's final error (its measurement noise), and a laser whose response has changed since
(a TEC temperature step scales the FM response, a drift bends it) shows more. Besides the error, the
nonlinearity (best-fit line removed, what Fig. 2-4 plots) separates a slope change from a shape change.

Same analysis parameters as :func:`lidard.dsp.linearize.ilc.linearize` by default (ROI 0.8, learning region 0.92,
400 kHz measurement low pass), so the figures compare with its iterations. Pure numpy/scipy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from ._measure import ChirpGeometry, _Analyzer, _directions
from ..spectrum.instfreq import check_finite_array


@dataclass(frozen=True)
class ChirpResidual:
    """RMS frequency errors (Hz) of one set of monitor records against the ideal linear chirp."""

    up_error_hz: float
    down_error_hz: float
    up_nonlinearity_hz: float           # best-fit line removed (slope errors do not count)
    down_nonlinearity_hz: float
    noise_floor_hz: float               # from two halves of the records (NaN with one record)
    excursion_hz: float
    records: int

    @property
    def error_hz(self) -> float:
        """RMS error over both ramps."""
        return math.sqrt(0.5 * (self.up_error_hz ** 2 + self.down_error_hz ** 2))

    @property
    def relative(self) -> float:
        """``error_hz`` as a fraction of the chirp excursion (the equivalent relative nonlinearity)."""
        return self.error_hz / self.excursion_hz


def chirp_residual(records: ArrayLike, drive_v: ArrayLike, chirp: ChirpGeometry, *, roi: float = 0.8,
                   learn: float = 0.92, meas_cutoff_hz: float = 400e3) -> ChirpResidual:
    """The error of the chirp that ``drive_v`` produced, from monitor records of it.

    ``records``: shape ``(n, 2 ramp_s fs_adc_hz)``, each aligned with the start of the drive period;
    real (one photodiode) or complex I + jQ (quadrature monitor), as the ILC's ``measure`` returns.
    """
    chirp = chirp.checked()
    u = check_finite_array("drive_v", drive_v, ndim=(1,))
    y = np.asarray(records)
    y = y.astype(np.complex128 if np.iscomplexobj(y) else np.float64)
    if y.ndim == 1:
        y = y[None, :]
    an = _Analyzer(chirp, roi=roi, learn=learn, meas_cutoff_hz=meas_cutoff_hz, directions=_directions(u))
    if y.ndim != 2 or y.shape[1] != an.n_adc:
        raise ValueError(f"records have shape {y.shape}; expected (n, {an.n_adc}) (one drive period each)")
    if abs(u.size - an.n_drive) > 0.5:
        raise ValueError(f"drive_v has {u.size} samples; one period 2 ramp_s fs_drive_hz is {an.n_drive}")
    check_finite_array("monitor records", y.view(np.float64))
    a = an.analyse(y, u)
    return ChirpResidual(up_error_hz=a.err_rms[0], down_error_hz=a.err_rms[1], up_nonlinearity_hz=a.rms[0],
                         down_nonlinearity_hz=a.rms[1], noise_floor_hz=a.noise, excursion_hz=chirp.excursion_hz,
                         records=int(y.shape[0]))


__all__ = ["ChirpGeometry", "ChirpResidual", "chirp_residual"]
