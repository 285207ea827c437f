"""The coherent receiver's I/Q imbalance, measured on whatever is in front of the sensor.

With ``adc.iq`` the beat arrives on two digitizer channels from a 90-degree hybrid whose quadrature is
not exactly 90 degrees and whose two photodiode chains differ in gain (lidard.dsp.ranging.iqbalance). Each
target's beat tone, seen on both channels, tells the gain ratio and the phase error directly (the
ratio of the two channels' spectra at the tone), so the procedure needs no known geometry: scan the
centre region with the raw records kept (lidard.raw), take every ramp with a tone 30 dB above its
noise, average. Static or moving targets, any range inside the gate. A scene that gives too few tones
(nothing in front of the sensor) is refused with the count, as is an instrument without the receiver.

The fit is stored as a calibration record of kind ``iq`` (fitted: gain, phase_rad; residuals: their
standard errors, the tones used, the image rejection before and after) and every later scan's DSP
removes it (:class:`.applied.AppliedCalibrations`).
"""

from __future__ import annotations

import shutil
import tempfile
import threading
from pathlib import Path

import numpy as np

from ...dsp.ranging.iqbalance import ImbalanceFit, estimate_imbalance
from ...dsp.spectrum.window import DspInputError
from ..types import CalibrationResult, ScanRequest
from .range import CalibrationRefused, centre_request

#: the centre region scanned (pixels per side): 256 pixels x 2 ramps, ~50 ms of hardware time
REGION_PX = 16


def iq_request(optics, max_range_m: float = 2.0, region_px: int = REGION_PX) -> ScanRequest:
    """The centre ``region_px`` x ``region_px`` pixels (bonded rows only), one chirp each, no outputs."""
    return centre_request(optics, max_range_m, max(1, region_px // 2), averages=1)


def ramps_of_capture(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every recorded ramp's I and Q (the used central part, as the DSP takes it): (n_ramps, n) each."""
    from ...raw.capture import RawCapture   # zarr is loaded only by procedures that record
    cap = RawCapture(path)
    d = cap.attrs["dsp"]
    r = int(d["ramp_samples"])
    n = int(r * float(d["use_fraction"])) & ~1
    a = (r - n) // 2
    i_parts, q_parts = [], []
    for k in range(cap.n_chunks):
        ch = cap.chunk(k)
        i = ch.channel("beat_i", cap.channels, cap.averages)
        q = ch.channel("beat_q", cap.channels, cap.averages)
        for r0 in (0, r):
            i_parts.append(i[..., r0 + a:r0 + a + n].reshape(-1, n))
            q_parts.append(q[..., r0 + a:r0 + a + n].reshape(-1, n))
    if not i_parts:
        return np.zeros((0, 8)), np.zeros((0, 8))
    return np.concatenate(i_parts), np.concatenate(q_parts)


def require_iq_receiver(instrument) -> None:
    """Refuse (before any light or linearization) an instrument without the coherent receiver."""
    if not getattr(instrument, "iq_receiver", False):
        raise CalibrationRefused("I/Q calibration: this instrument has one photodiode (adc.iq = false); "
                                 "the imbalance belongs to a coherent receiver's hybrid")


def measure_iq(instrument, optics, linearization: CalibrationResult, *, max_range_m: float = 2.0,
               region_px: int = REGION_PX) -> tuple[ImbalanceFit, dict]:
    """Scan the centre region keeping the raw I/Q records, fit the imbalance; answers the fit and a
    summary (pixels, ramps, tones) for the record. Raises :class:`CalibrationRefused` with the reason."""
    require_iq_receiver(instrument)
    req = iq_request(optics, max_range_m, region_px)
    tmp = Path(tempfile.mkdtemp(prefix="lidard-iqcal-"))
    try:
        res = instrument.run_scan(req, lambda _p: None, threading.Event(), linearization, raw_path=tmp / "raw")
        if res.partial:
            raise CalibrationRefused(f"I/Q calibration scan stopped early: {res.stop_reason or 'cancelled'}")
        i, q = ramps_of_capture(tmp / "raw")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    try:
        fit = estimate_imbalance(i, q, window=instrument.cfg.scan.window)
    except DspInputError as exc:
        raise CalibrationRefused(f"I/Q calibration refused: {exc}") from None
    return fit, {"pixels_scanned": int(res.pixels_scanned), "ramps": int(len(i)), "max_range_m": float(max_range_m)}
