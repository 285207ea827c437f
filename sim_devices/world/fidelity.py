"""Model only what the scene needs: which effects a capture can skip, and the ledger of what it did.

The bench decides per captured batch. An effect is skipped only when its
contribution to the measurement is below a stated bound; the rule and its bound are here, the
ledger goes into each scan's sidecar (``sim.fidelity``: batches modelled / skipped per effect).

**Laser phase noise on the beat** (dissertation §2.3, eqs. 2-14/2-15). The beat of a hit at round
trip tau carries the differential phase dphi(t) = phi(t) - phi(t - tau) of a Wiener phase
(Lorentzian linewidth dnu = 1 / (pi tau_c): the frequency noise is white, two-sided PSD 2 pi dnu
(rad/s)^2/Hz, so S_phi(f) = dnu / (2 pi f^2)). Two things can change a measurement:

* the coherent peak: E[exp(j dphi)] = exp(-Var/2) with Var = 2 pi dnu tau = 2 tau / tau_c, so the
  peak power drops by exp(-2 pi dnu tau) (the rest goes to the pedestal, which reaches out to
  ~1/tau). Bound: ``PEAK_LOSS_DB`` (0.1 dB; a pixel's own SNR estimate scatters by more);
* the frequency estimate: inside the digitizer's band (f << 1/tau), |1 - exp(-j 2 pi f tau)|^2 =
  (2 pi f tau)^2 turns S_phi into a white S_pn = 2 pi dnu tau^2 (rad^2/Hz, two-sided). The
  receiver's white noise (one-sided ASD a) acts on a tone of amplitude A as phase noise of
  two-sided PSD S_w = a^2 / A^2. Each scatters a frequency fitted over T seconds by 12 S / T^3: the
  phase noise adds rho = S_pn / S_w = 2 pi dnu tau^2 A^2 / a^2 to the noise's range variance, and
  on its own sigma_R = c sqrt(h 12 S_pn / T^3) / (2 pi 2 kappa) (:func:`phase_noise_range_std_m`),
  with h = sum w^2 t^2 / (sum w t^2)^2 over the uniform case = 2.34 for the Hann-weighted fit the
  DSP makes: 25 um at 0.9 m with the default DFB over a 64 us fit. Bound: ``RHO_MAX`` = 0.01 (the
  range std grows by <= 0.5 %) OR ``RANGE_STD_M`` = 30 um (1/10 of the CAL letters' 0.3 mm
  target; +2.6 % on their 0.13 mm RMS in quadrature), with T = 0.8 of a ramp (the DSP fits 0.9:
  conservative).

Why the in-band PSD and not the sampled model's: the synthesis samples dphi at the ADC rate fs
without the digitizer's anti-alias filter acting on the pedestal, so for tau < 1/fs its samples are
independent with variance 2 pi dnu tau, an in-band PSD 2 pi dnu tau / fs: 1 / (tau fs) times the
physical one (~30x for the CAL letters at 5 MS/s). A real digitizer removes the pedestal beyond its
band; skipping there is the more faithful choice, and the test measures both regimes.

Skipped only when no monitor-MZI channel is captured (its 200 ns delay always needs the phase noise),
the receiver noise is on, and both bounds hold for every hit of the batch. With the default DFB
(tau_c = 0.64 us) that is the CAL letters at 0.8-0.9 m; far walls, bright close targets and the
broad-linewidth preset (0.1 us) keep it. tests/sim_devices/world/test_fidelity_phase_noise.py
measures the skipped contribution against both bounds.
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from lidard.physics.constants import C_M_PER_S

PEAK_LOSS_DB = 0.1
RHO_MAX = 0.01
RANGE_STD_M = 30e-6
FIT_FRACTION = 0.8
HANN_VARIANCE_FACTOR = 2.34   # sum w^2 t^2 / (sum w t^2)^2, Hann weights, over the uniform case

EFFECTS = ("phase_noise", "doppler", "speckle", "mixed_pixels")


def phase_noise_peak_loss_db(tau_s: float, linewidth_hz: float) -> float:
    """Coherent peak-power loss of a beat at round trip ``tau_s``: 10 log10 exp(2 pi dnu tau)."""
    return 10.0 * math.log10(math.e) * 2.0 * math.pi * linewidth_hz * tau_s


def phase_noise_range_std_m(tau_s: float, linewidth_hz: float, ramp_s: float, chirp_rate_hz_per_s: float) -> float:
    """Range scatter the differential phase noise adds to a frequency fitted over one ramp."""
    s0 = 2.0 * math.pi * linewidth_hz * tau_s ** 2
    sigma_omega = math.sqrt(HANN_VARIANCE_FACTOR * 12.0 * s0 / ramp_s ** 3)
    return C_M_PER_S * sigma_omega / (2.0 * math.pi * 2.0 * abs(chirp_rate_hz_per_s))


def phase_noise_variance_fraction(tau_s, amplitude_v, linewidth_hz: float, noise_asd_v_per_rthz: float):
    """rho = S_pn / S_w per hit: the share the phase noise adds to the white-noise range variance."""
    tau = np.asarray(tau_s, dtype=np.float64)
    amp = np.asarray(amplitude_v, dtype=np.float64)
    return 2.0 * np.pi * linewidth_hz * tau ** 2 * amp ** 2 / noise_asd_v_per_rthz ** 2


def phase_noise_negligible(tau_s, amplitude_v, linewidth_hz: float, noise_asd_v_per_rthz: float,
                           ramp_s: float, chirp_rate_hz_per_s: float) -> bool:
    """True when every hit's phase noise is under the bounds: peak loss, and added range scatter
    (relative to the noise's or absolute)."""
    if linewidth_hz <= 0:
        return True
    tau = np.asarray(tau_s, dtype=np.float64)
    if tau.size == 0:
        return True
    t_max = float(tau.max())
    if phase_noise_peak_loss_db(t_max, linewidth_hz) > PEAK_LOSS_DB:
        return False
    if phase_noise_range_std_m(t_max, linewidth_hz, FIT_FRACTION * ramp_s, chirp_rate_hz_per_s) <= RANGE_STD_M:
        return True
    if not noise_asd_v_per_rthz > 0:
        return False   # no receiver noise to hide under
    rho = phase_noise_variance_fraction(tau, amplitude_v, linewidth_hz, noise_asd_v_per_rthz)
    return bool(rho.max() <= RHO_MAX)


class FidelityLedger:
    """Counts of captured batches per effect: ``modelled`` or ``skipped`` (with the rule that skipped)."""

    def __init__(self) -> None:
        self.modelled: Counter[str] = Counter()
        self.skipped: Counter[str] = Counter()

    def note(self, effect: str, modelled: bool) -> None:
        (self.modelled if modelled else self.skipped)[effect] += 1

    def snapshot(self) -> dict:
        return {"modelled": dict(self.modelled), "skipped": dict(self.skipped),
                "rules": {"phase_noise": f"skipped when no monitor channel is captured and every hit has a "
                                         f"peak loss <= {PEAK_LOSS_DB} dB and adds <= {RANGE_STD_M * 1e6:g} um "
                                         f"of range scatter or <= {RHO_MAX:g} of the noise's range variance "
                                         "(sim_devices/world/fidelity.py)",
                          "doppler": "modelled only for hits on moving targets",
                          "speckle": "modelled only for targets with speckle = true",
                          "mixed_pixels": "modelled for a batch with a beam whose footprint crosses a target outline "
                                          "(sub-rays only there, on every scene unless it sets mixed_pixels = "
                                          "false; sim_devices/world/footprint.py)"}}

