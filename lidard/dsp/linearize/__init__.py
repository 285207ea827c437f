"""Chirp linearization: iterative learning pre-distortion of the laser drive (dissertation §2.2).

:mod:`.ilc` the learning loop (:func:`lidard.dsp.linearize.ilc.linearize`); :mod:`.quadrature` the
chirp measured from a quadrature monitor MZI; :mod:`.chirpcheck` one measurement without learning
(the linearization health check). The measurement (``_measure``) and the update law (``_update``)
are private to the loop. Built on :mod:`lidard.dsp.spectrum` only.
"""

__all__ = ["chirpcheck", "ilc", "quadrature"]
