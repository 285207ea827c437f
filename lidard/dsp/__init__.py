"""Pure DSP core of lidard: range FFT, sub-bin estimators, CFAR, up/down-ramp velocity (§2.1, §2.4).

numpy/scipy only: no I/O, no logging, no clock.
"""

from lidard.dsp.cfar import CfarMethod, Detections, ca_cfar_alpha, cfar_detect
from lidard.dsp.cfar_os import os_cfar_alpha
from lidard.dsp.crlb import crlb_freq_var, crlb_freq_var_post_fft, post_fft_snr
from lidard.dsp.chain import PeakMeasurements, measure_peaks
from lidard.dsp.estimators import DEFAULT_METHOD, ESTIMATORS, EstimatorName, estimate
from lidard.dsp.rangefft import C_M_PER_S, RangeFFT
from lidard.dsp.velocity import pair_up_down
from lidard.dsp.window import DspInputError, WindowInfo, WindowName, get_window, window_info

__all__ = [
    "C_M_PER_S",
    "DEFAULT_METHOD",
    "ESTIMATORS",
    "CfarMethod",
    "Detections",
    "DspInputError",
    "EstimatorName",
    "PeakMeasurements",
    "RangeFFT",
    "WindowInfo",
    "WindowName",
    "ca_cfar_alpha",
    "cfar_detect",
    "crlb_freq_var",
    "crlb_freq_var_post_fft",
    "estimate",
    "get_window",
    "measure_peaks",
    "os_cfar_alpha",
    "pair_up_down",
    "post_fft_snr",
    "window_info",
]
