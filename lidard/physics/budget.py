"""FMCW LiDAR link budget and noise, dissertation §2.4.1 (eqs. 2-9 to 2-21) and §4.4.2.

Every component is expressed as a single-sided amplitude spectral density (ASD, V/sqrt(Hz)) of the
voltage the ADC records, so that ratios are the SNRs seen in the FFT spectrum (eq. 2-13). SNRs in dB
here are amplitude ratios, 20 log10(ASD_signal / ASD_noise), as in Figs. 2-8, 2-9 and 4-32.

Two set-ups are modelled by :class:`LinkParams`:

* ``LinkParams.table_2_2()``: the dissertation's reference design (MZI reference arm, balanced
  detection with -25 dB CMRR, 50 mW laser). With it the signal meets shot noise near 220 m (Fig. 2-8)
  and the shot-noise-limited reference-power window is 3.40 uW < P_ref < 337 uW (eqs. 4-29, 4-33).
* the §4.4 FPSA LiDAR: the -34 dB back-reflection at the fibre array is the local oscillator (single
  photodiode, so CMRR = 0 dB), ~1 mW leaves the scanner and the return passes the FPSA's Table 4-4
  losses again. :func:`lidard.config` builds it from the configuration.

Beat amplitude: eq. 2-11 as written, I_AC = R sqrt(P_ref P_rx), also for the §4.4 single-photodiode
circulator set-up, whose ideal (matched polarisation and mode) term would be twice that; the bench
keeps eq. 2-11 because the dissertation derives §4.4 from it and it reproduces Fig. 4-32's ~28 dB
(29.1 dB at 0.8 m, against 35.1 dB with the ideal factor): see docs/physics.md.

The ADC term follows eq. 2-19 literally, (V/2^N)^2 / B_ADC (one LSB^2 spread over B_ADC), which is
12x the variance of an ideal uniform quantizer (LSB^2/12); :func:`quantization_asd` gives the latter
for simulation at an actual sample rate.

Pure numpy/scipy; no I/O.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np
from numpy.typing import ArrayLike
from typing import Any
from collections.abc import Callable

from .constants import C_M_PER_S, E_CHARGE_C, K_BOLTZMANN_J_PER_K


def _bisect_root(f: Callable[[float], float], a: float, b: float, xtol: float) -> float:
    """A root of f in [a, b] where f(a) > 0 >= f(b), to xtol (bisection: about 35 steps here).

    Not scipy.optimize.brentq: importing scipy.optimize costs about a second of start-up of every
    command that needs a link budget (``lidarctl budget``, config loading).
    """
    while b - a > xtol:
        m = 0.5 * (a + b)
        if f(m) > 0:
            a = m
        else:
            b = m
    return 0.5 * (a + b)


COMPONENTS = ("signal", "pedestal", "shot", "rin", "thermal", "adc", "ambient")
NOISE_COMPONENTS = COMPONENTS[1:]


def db_to_lin_power(db: float) -> float:
    return 10.0 ** (db / 10.0)


def optical_bandwidth_hz(bandwidth_m: float, wavelength_m: float) -> float:
    """Convert a receiver's optical bandwidth in wavelength to frequency: c dlambda / lambda^2."""
    return C_M_PER_S * bandwidth_m / wavelength_m**2


@dataclass(frozen=True)
class LinkParams:
    """Everything eqs. 2-9..2-21 need, in SI units.

    ``source_power_w`` is the power that both the reference and the probe derive from (the laser in
    Table 2-2, the light entering the fibre array in §4.4); ``ref_fraction`` and ``tx_fraction`` turn it
    into P_ref and P_tx so that a power sweep (Fig. 2-9, ``lidarctl budget --power``) scales both.
    """

    source_power_w: float
    ref_fraction: float            # P_ref / source (eq. 2-9: r_ref)
    tx_fraction: float             # P_tx / source (eta_tx (1 - r_ref) in Table 2-2)
    eta_rx: float                  # receiver optical efficiency (incl. FPSA return losses)
    rx_aperture_m: float           # d_rx
    wavelength_m: float
    ramp_s: float                  # T, one chirp
    coherence_time_s: float        # tau_c; inf for an ideal laser
    rin_db_per_hz: float           # RIN, dBc/Hz
    responsivity_a_per_w: float
    tia_gain_v_per_a: float
    cmrr_db: float                 # 0 dB for a single photodiode
    temperature_k: float
    adc_range_v: float
    adc_bits: int
    adc_bandwidth_hz: float
    ambient_psd_w_per_hz: float
    optical_bandwidth_hz: float
    reflectivity: float = 0.1
    incidence_rad: float = 0.0

    @classmethod
    def table_2_2(cls, **overrides: Any) -> LinkParams:
        """Table 2-2 of the dissertation."""
        wl = 1550e-9
        p = cls(
            source_power_w=50e-3, ref_fraction=0.1, tx_fraction=0.7 * (1 - 0.1), eta_rx=0.5,
            rx_aperture_m=10e-3, wavelength_m=wl, ramp_s=80e-6, coherence_time_s=0.64e-6,
            rin_db_per_hz=-150.0, responsivity_a_per_w=0.95, tia_gain_v_per_a=1.6e4, cmrr_db=-25.0,
            temperature_k=300.0, adc_range_v=1.0, adc_bits=8, adc_bandwidth_hz=500e6,
            ambient_psd_w_per_hz=1.57e-20, optical_bandwidth_hz=optical_bandwidth_hz(1e-9, wl),
            reflectivity=0.1, incidence_rad=0.0,
        )
        return replace(p, **overrides)

    def with_(self, **changes: Any) -> LinkParams:
        return replace(self, **changes)

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    # -- powers and currents ----------------------------------------------------------------------
    @property
    def p_ref_w(self) -> float:
        return self.ref_fraction * self.source_power_w

    @property
    def p_tx_w(self) -> float:
        return self.tx_fraction * self.source_power_w

    def received_power_w(self, distance_m: ArrayLike, reflectivity: ArrayLike | None = None,
                         incidence_rad: ArrayLike | None = None) -> np.ndarray:
        """Eq. 2-10: Lambertian return collected by an aperture d_rx at distance d."""
        rho = self.reflectivity if reflectivity is None else reflectivity
        th = self.incidence_rad if incidence_rad is None else incidence_rad
        d = np.asarray(distance_m, dtype=np.float64)
        return (self.p_tx_w * np.asarray(rho) * np.cos(th)
                * self.rx_aperture_m**2 / (4.0 * d**2) * self.eta_rx)

    def i_ac_a(self, p_rx_w: ArrayLike) -> np.ndarray:
        """Eq. 2-11: beat amplitude of the photocurrent."""
        return self.responsivity_a_per_w * np.sqrt(self.p_ref_w * np.asarray(p_rx_w))

    def i_dc_a(self, p_rx_w: ArrayLike) -> np.ndarray:
        """Eq. 2-12."""
        return self.responsivity_a_per_w * (self.p_ref_w + np.asarray(p_rx_w))


def asd_components(p: LinkParams, distance_m: ArrayLike, *, reflectivity: ArrayLike | None = None,
                   incidence_rad: ArrayLike | None = None) -> dict[str, np.ndarray]:
    """All ASDs (V/sqrt(Hz)) of eqs. 2-14..2-21 at the given distance(s), broadcast over arrays."""
    d = np.asarray(distance_m, dtype=np.float64)
    p_rx = p.received_power_w(d, reflectivity, incidence_rad)
    i_ac = p.i_ac_a(p_rx)
    i_dc = p.i_dc_a(p_rx)
    g = p.tia_gain_v_per_a
    tau = 2.0 * d / C_M_PER_S
    if np.isinf(p.coherence_time_s):
        decay = np.ones_like(tau)
        pedestal_factor = np.zeros_like(tau)
    else:
        x = 2.0 * tau / p.coherence_time_s
        decay = np.exp(-x)
        # 1 - (1 + x) e^-x, written with expm1 so it stays accurate for tiny x (short ranges).
        pedestal_factor = p.coherence_time_s * (-np.expm1(-x) - x * np.exp(-x))
    signal = g * np.sqrt(i_ac**2 / 2.0 * p.ramp_s * decay)                       # eq. 2-14
    pedestal = g * np.sqrt(i_ac**2 / 2.0 * np.maximum(pedestal_factor, 0.0))      # eq. 2-15
    shot = g * np.sqrt(2.0 * E_CHARGE_C * i_dc)                                  # eq. 2-16
    cmrr = 10.0 ** (p.cmrr_db / 20.0)
    rin = g * cmrr * np.sqrt(i_dc**2 * db_to_lin_power(p.rin_db_per_hz))        # eq. 2-17
    thermal = np.sqrt(4.0 * K_BOLTZMANN_J_PER_K * p.temperature_k * g) * np.ones_like(d)  # eq. 2-18
    adc = np.sqrt((p.adc_range_v / 2.0**p.adc_bits) ** 2 / p.adc_bandwidth_hz) * np.ones_like(d)  # 2-19
    r = p.responsivity_a_per_w
    amb_amb = g * np.sqrt(4 * r**2 * p.ambient_psd_w_per_hz**2 * p.optical_bandwidth_hz)  # eq. 2-20
    amb_ref = g * np.sqrt(4 * r**2 * p.p_ref_w * p.ambient_psd_w_per_hz)                  # eq. 2-21
    ambient = np.sqrt(amb_amb**2 + amb_ref**2) * np.ones_like(d)
    return {"signal": signal, "pedestal": pedestal, "shot": shot, "rin": rin,
            "thermal": thermal, "adc": adc, "ambient": ambient}


def total_noise_asd(components: dict[str, np.ndarray]) -> np.ndarray:
    return np.sqrt(sum(np.asarray(components[k]) ** 2 for k in NOISE_COMPONENTS))


def snr_db(p: LinkParams, distance_m: ArrayLike, **kw: Any) -> np.ndarray:
    """Amplitude SNR of the spectral peak over the total noise floor (dB, 20 log10)."""
    c = asd_components(p, distance_m, **kw)
    return 20.0 * np.log10(c["signal"] / total_noise_asd(c))


def max_range_m(p: LinkParams, *, against: str = "total", lo_m: float = 1e-3, hi_m: float = 1e6) -> float:
    """Distance at which the signal ASD falls to the noise (SNR = 1).

    ``against`` = "total" (all noises, incl. the phase-noise pedestal) or one component name, e.g.
    "shot" for the crossing of Fig. 2-8.
    """
    def margin(log_d: float) -> float:
        c = asd_components(p, np.exp(log_d))
        noise = total_noise_asd(c) if against == "total" else c[against]
        # the phase-noise decay can underflow the signal to 0 at absurd ranges: clamp, stay finite
        return float(np.log(max(float(c["signal"]), 1e-300) / float(noise)))

    if against != "total" and against not in NOISE_COMPONENTS:
        raise ValueError(f"max_range_m: against must be 'total' or one of {NOISE_COMPONENTS}, got {against!r}")
    a, b = np.log(lo_m), np.log(hi_m)
    if margin(a) <= 0:
        return 0.0
    if margin(b) > 0:
        return float("inf")
    return float(np.exp(_bisect_root(margin, float(a), float(b), xtol=1e-9)))


def shot_limited_ref_window_w(p: LinkParams) -> tuple[float, float]:
    """Reference powers between which shot noise dominates thermal and RIN noise.

    Lower bound eq. 4-28/4-29: 4 k T / (2 e G R); upper bound eq. 4-32/4-33: 2 e / (R RIN)
    (single photodiode, CMRR = 0 dB, as in §4.4.2).
    """
    r = p.responsivity_a_per_w
    lower = 4 * K_BOLTZMANN_J_PER_K * p.temperature_k / (2 * E_CHARGE_C * p.tia_gain_v_per_a * r)
    upper = 2 * E_CHARGE_C / (r * db_to_lin_power(p.rin_db_per_hz))
    return lower, upper


def quantization_asd(adc_range_v: float, bits: int, sample_rate_hz: float) -> float:
    """ASD of an ideal uniform quantizer sampled at fs: sqrt(LSB^2/12 / (fs/2))."""
    lsb = adc_range_v / 2.0**bits
    return float(np.sqrt(lsb**2 / 12.0 / (sample_rate_hz / 2.0)))


def monitor_noise_asd(amplitude_v: float, power_w: float, responsivity_a_per_w: float,
                      rin_db_per_hz: float) -> dict[str, float]:
    """Shot and RIN ASDs (V/sqrt(Hz)) of the monitor-MZI channel (§2.2's MZI on one photodiode).

    One output of an MZI with full fringe visibility carries I(t) = R P_mon (1 + cos dPhi): DC and
    AC amplitude are both R P_mon, so the TIA gain is G = amplitude_v / (R P_mon). Then, as eqs.
    2-16 and 2-17 for the LiDAR receiver: shot = G sqrt(2 q R P_mon) = amplitude_v sqrt(2 q /
    (R P_mon)) and RIN = G R P_mon sqrt(RIN) = amplitude_v sqrt(RIN). The ADC's quantization of the
    channel is added where the channel is digitized (it depends on the record format).
    """
    if not (power_w > 0 and responsivity_a_per_w > 0 and amplitude_v >= 0):
        raise ValueError(f"monitor_noise_asd: need power_w > 0, responsivity > 0, amplitude_v >= 0; got "
                         f"{power_w!r}, {responsivity_a_per_w!r}, {amplitude_v!r}")
    shot = amplitude_v * float(np.sqrt(2.0 * E_CHARGE_C / (responsivity_a_per_w * power_w)))
    rin = amplitude_v * float(np.sqrt(db_to_lin_power(rin_db_per_hz)))
    return {"shot": shot, "rin": rin, "total": float(np.hypot(shot, rin))}


def budget_report(p: LinkParams, distance_m: float) -> dict[str, Any]:
    """The JSON object `lidarctl budget --json` prints."""
    c = asd_components(p, distance_m)
    noise = float(total_noise_asd(c))
    return {
        "distance_m": float(distance_m),
        "source_power_w": p.source_power_w,
        "p_ref_w": p.p_ref_w,
        "p_tx_w": p.p_tx_w,
        "p_rx_w": float(p.received_power_w(distance_m)),
        "asd_v_per_rthz": {k: float(v) for k, v in c.items()},
        "noise_total_v_per_rthz": noise,
        "snr_db": float(20 * np.log10(float(c["signal"]) / noise)),
        "max_range_m": max_range_m(p),
        "dominant_noise": max(NOISE_COMPONENTS, key=lambda k: float(c[k])),
    }
