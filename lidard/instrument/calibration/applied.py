"""The geometric calibrations an instrument applies to its linearizations and scans.

* range scale and zero (:mod:`.range`): the effective monitor MZI delay replaces the configuration's
  nominal ``monitor.delay_s`` as the ILC's target (§2.2) and in the phase-noise compensation (§2.3), so
  the chirp rate itself becomes right; the zero offset is subtracted from every range;
* pointing (:mod:`.pointing`): beam directions come from ``optics.with_pointing(fit)`` (eq. 4-1 with
  the fitted deviations);
* I/Q imbalance (:mod:`.iq`, only with ``adc.iq``): the DSP removes the fitted gain ratio and phase
  error of the coherent receiver before its two-sided spectrum (lidard.dsp.ranging.iqbalance).

The job worker loads the newest stored record of each kind made on the instrument's own set-up
(:mod:`.setup`) and hands them over before every scan and linearization; an instrument with none
applies the nominal values, its scans say ``calibrated: {"range": false, "pointing": false}`` and,
when records exist for another set-up, ``uncalibrated_reason`` says why they were not used.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ...physics.optics import Pointing


@dataclass(frozen=True)
class AppliedCalibrations:
    range_id: str | None = None
    delay_s: float | None = None          # tau_eff; None: the configuration's nominal monitor.delay_s
    zero_offset_m: float = 0.0
    pointing_id: str | None = None
    pointing: Pointing | None = None
    iq_id: str | None = None
    iq_imbalance: tuple[float, float] = (1.0, 0.0)   # the I/Q receiver's (gain ratio, phase error rad)
    #: why stored records were not applied (made on another set-up), one sentence per kind
    notes: tuple[str, ...] = ()
    #: the range fit's standard errors and their covariance (s, m, s m); None: not stated by the record
    delay_stderr_s: float | None = None
    zero_offset_stderr_m: float | None = None
    delay_zero_offset_cov: float | None = None

    @classmethod
    def from_records(cls, range_rec: Any = None, pointing_rec: Any = None, iq_rec: Any = None,
                     notes: tuple[str, ...] = ()) -> AppliedCalibrations:
        """From stored records (``.id``, ``.fitted``; lidard.store.CalibrationRecord)."""
        kw: dict[str, Any] = {"notes": tuple(notes)}
        if iq_rec is not None:
            kw.update(iq_id=iq_rec.id, iq_imbalance=(float(iq_rec.fitted["gain"]), float(iq_rec.fitted["phase_rad"])))
        if range_rec is not None:
            f = range_rec.fitted
            kw.update(range_id=range_rec.id, delay_s=float(f["delay_s"]), zero_offset_m=float(f["zero_offset_m"]),
                      **{k: float(f[k]) for k in ("delay_stderr_s", "zero_offset_stderr_m", "delay_zero_offset_cov")
                         if f.get(k) is not None})
        if pointing_rec is not None:
            f = pointing_rec.fitted
            kw.update(pointing_id=pointing_rec.id,
                      pointing=Pointing(focal_scale=float(f["focal_scale"]),
                                        decentre_px=(float(f["decentre_px"][0]), float(f["decentre_px"][1])),
                                        rotation_rad=float(f["rotation_rad"]), k1=float(f["k1"])))
        return cls(**kw)

    def delay_or(self, nominal_s: float) -> float:
        return float(nominal_s) if self.delay_s is None else float(self.delay_s)

    def optics(self, optics):
        return optics if self.pointing is None else optics.with_pointing(self.pointing)

    def calibrated(self, linearization: bool, iq: bool = False) -> dict[str, bool]:
        """What a scan was computed with; ``iq``: the instrument has the I/Q receiver (adc.iq), whose
        imbalance calibration is then listed too."""
        out = {"range": self.range_id is not None, "pointing": self.pointing_id is not None,
               "linearization": bool(linearization)}
        if iq:
            out["iq"] = self.iq_id is not None
        return out

    @property
    def uncalibrated_reason(self) -> str | None:
        """Why stored calibrations were left unused (None when nothing was), for the scan record."""
        return "; ".join(self.notes) or None

    def range_uncertainty_m(self, range_m: float) -> float | None:
        """The 1-sigma range error the range calibration leaves at ``range_m``: a range scales with the
        effective delay (dR/dtau = R / tau) and the zero offset is subtracted, so
        sigma^2 = (R/tau)^2 s_tau^2 + s_z0^2 - 2 (R/tau) cov(tau, z0). None without a range record or
        when the record states no standard errors (a record without the covariance counts it 0)."""
        if self.range_id is None or self.delay_s is None or self.delay_stderr_s is None \
                or self.zero_offset_stderr_m is None:
            return None
        k = float(range_m) / self.delay_s
        var = (k * self.delay_stderr_s) ** 2 + self.zero_offset_stderr_m ** 2 - 2 * k * (self.delay_zero_offset_cov or 0.0)
        return float(max(var, 0.0) ** 0.5)

    def meta(self, nominal_delay_s: float, max_range_m: float | None = None) -> dict[str, Any]:
        """What a scan's sidecar records about the geometry it was computed with; ``max_range_m``: the
        scan's range gate, where the range calibration's uncertainty is stated."""
        return {"range_calibration_id": self.range_id, "pointing_calibration_id": self.pointing_id,
                "range_uncertainty_at_m": max_range_m,
                "range_uncertainty_m": None if max_range_m is None else self.range_uncertainty_m(max_range_m),
                "monitor_delay_s": self.delay_or(nominal_delay_s), "zero_offset_m": self.zero_offset_m,
                "pointing": (self.pointing or Pointing()).as_dict(),
                "iq_calibration_id": self.iq_id, "iq_gain": self.iq_imbalance[0], "iq_phase_rad": self.iq_imbalance[1]}
