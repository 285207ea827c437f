"""The false-point rate: what ``pfa`` states, and the per-ramp detector's level that gives it.

A point is a hypothesis (range cell, radial velocity) whose predicted lines are detected on both
ramps: the up ramp at |f_R - f_D|, the down ramp at |f_R + f_D| (:mod:`.lines`). In noise alone the
two ramps are independent records, so a given hypothesis passes with probability q^2 when the
per-ramp detector (OS-CFAR) alarms on a cell with probability q. A range cell holds ``m`` such
hypotheses that noise can complete without any further evidence (:func:`hypotheses_per_cell`), so
the rate of false points per range cell is

    P_point = m q^2        and the detector runs at        q = sqrt(P_point / m)

(much looser than P_point: the per-ramp search finds candidates, the pair decides). q is a
probability per cell whatever the number K of records a pixel averages: the detector meets it with the
threshold of Gamma(K) noise cells (lidard.dsp.detect.os_gamma), and the two ramps stay independent. ``pfa`` of the
frame DSP (``scan.pfa``) is P_point: the expected number of valid false points per range cell of the
searched band (one FFT bin of the ramp, c / 2B) in noise-only records, the rate measured by
benchmarks/resolution_table.py (docs/measured/25_joint_model.md).

``m`` by chirp shape, with ``df`` the ramp's cell (fs / N):

* triangle with a speed prior (real or I/Q): the down line lies within 2 |f_D|max of the up line,
  m = 2 x 2 |f_D|max / df cells (at most the band's cells);
* three-segment (no prior): a pair needs the CW segment's beat at the |f_D| it predicts, except where
  that |f_D| lies inside the CW spectrum's DC guard (no beat can be seen there, none is needed): the
  static hypotheses, |f_up - f_dn| < 2 x guard, m = 2 x 2 guard / df. Pairs that need a CW beat also
  need a noise CW line in the band their regime predicts, tested at q over the band's cells
  (lidard.dsp.ranging.threeseg): their rate, at most 2 x band cells x q^3, is left out of m.

Pure python.
"""

from __future__ import annotations

import math

#: the per-ramp detector's level is kept below this (OS-CFAR's threshold factor is tabulated for
#: pfa < 0.1, lidard.dsp.detect.cfar): a point rate so high that the ramps would need more is refused
MAX_RAMP_PFA = 0.05


def ramp_pfa(point_pfa: float, hypotheses: float) -> float:
    """The per-ramp, per-cell false-alarm probability q = sqrt(P_point / m) (module doc)."""
    if not 0.0 < point_pfa < 1.0:
        raise ValueError(f"pfa (false points per range cell) must be in (0, 1), got {point_pfa!r}")
    if not hypotheses >= 1.0:
        raise ValueError(f"hypotheses per range cell must be >= 1, got {hypotheses!r}")
    q = math.sqrt(point_pfa / hypotheses)
    if q > MAX_RAMP_PFA:
        raise ValueError(f"pfa={point_pfa:g} false points per range cell needs a per-ramp level {q:.3g} "
                         f"> {MAX_RAMP_PFA}: too high a false-point rate")
    return q


def hypotheses_per_cell(*, ramp_cell_hz: float, band_cells: int, doppler_max_hz: float,
                        static_guard_hz: float | None = None) -> float:
    """m of the module doc. ``static_guard_hz``: the three-segment chirp's CW DC guard (None: the
    triangle's speed prior ``doppler_max_hz`` bounds the pairs)."""
    width = 2.0 * static_guard_hz if static_guard_hz is not None else 2.0 * doppler_max_hz
    return float(min(max(2.0 * width / ramp_cell_hz, 1.0), max(band_cells, 1)))
