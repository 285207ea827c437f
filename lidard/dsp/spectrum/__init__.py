"""From samples to spectra: the ground floor of the DSP (dissertation §2.1.1, §2.2, §2.4).

:mod:`.window` the spectral windows and the DSP's input error; :mod:`.rangefft` the range FFT and its
bins; :mod:`.dtft` the DTFT near a peak that the sub-bin estimators evaluate; :mod:`.windowdtft` a window's
DTFT in closed form (the model-order test's and the Jacobsen table's columns); :mod:`.instfreq` the
monitor MZI's instantaneous frequency (Hilbert transform); :mod:`.scratch` the hot path's per-thread
buffers; :mod:`.jit` the optional compiled passes, whose numba kernels (``_kernels``) load on first use.
Nothing here imports another room of :mod:`lidard.dsp`.
"""

__all__ = ["dtft", "instfreq", "jit", "rangefft", "scratch", "window", "windowdtft"]
