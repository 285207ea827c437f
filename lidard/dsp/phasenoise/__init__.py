"""Laser phase noise taken out of the beat with the monitor MZI (dissertation §2.3, Figs. 2-6, 2-7).

:mod:`.reconstruct` rebuilds the laser phase sample by sample (a quadrature monitor, any range);
:mod:`.compensate` compensates a beat with it (or with the real MZI's delayed copies, on its delay grid).
The frame front end that runs them before detection is :mod:`lidard.dsp.pnframe` (it builds on the
detection chain, one floor up). Built on :mod:`lidard.dsp.spectrum` only.
"""

__all__ = ["compensate", "reconstruct"]
