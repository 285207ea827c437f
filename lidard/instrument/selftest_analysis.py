"""Pure checks on self-test / bring-up readings: is the MEMS HV high enough to pull in the switches?

The FPSA's switches are electrostatic parallel-plate actuators with pull-in hysteresis (§4.2.6,
Fig. 4-15a: the 20x20 switch turns on at 32 V and off at 29 V). The HV583 drives each line with the
controller's HV, so an HV below the pull-in voltage actuates no switch, and an HV just above the
nominal pull-in leaves the switches whose own pull-in is higher (switch-to-switch spread) dark.
The self-test reads the emission monitor ("tap": a DC photodiode on the light leaving the chip) with
one pixel per line; these functions turn those readings plus the HV readback into a message that
names the HV, so an operator is not sent hunting for "stuck" switches that were never driven hard
enough. No I/O: the instrument calls them with what it measured.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["hv_margin_problem", "hv_pull_in_problem"]

#: Spread multiples that count as "every switch pulls in" (3 sigma: 99.87 % of switches each side).
SPREAD_SIGMAS = 3.0


def hv_margin_problem(hv_v: float, pull_in_v: float, spread_v: float = 0.0) -> str | None:
    """Bring-up check on the HV readback alone: a message if it cannot pull in every switch."""
    _finite("hv_v", hv_v)
    _finite("pull_in_v", pull_in_v)
    need = pull_in_v + SPREAD_SIGMAS * spread_v
    if hv_v < pull_in_v:
        return (f"HV {hv_v:.2f} V is below the switches' pull-in voltage {pull_in_v:.2f} V: no MEMS "
                f"switch can turn on (raise the HV to at least {need:.2f} V)")
    if hv_v < need:
        return (f"HV {hv_v:.2f} V is within the pull-in spread of the switches ({pull_in_v:.2f} V "
                f"+ {SPREAD_SIGMAS:g} x {spread_v:.2f} V): some switches will not turn on "
                f"(raise the HV to at least {need:.2f} V)")
    return None


def hv_pull_in_problem(tap_v: Sequence[float] | np.ndarray, hv_v: float, pull_in_v: float,
                       *, dark_v: float, spread_v: float = 0.0) -> str | None:
    """Self-test check: a message naming the HV when dark lines are explained by a low HV.

    ``tap_v``: the emission-monitor reading of each tested line (rows and columns, one pixel
    each); ``dark_v``: the level below which a reading means "no beam" (e.g. half the expected
    single-beam level, or several noise sigmas). Returns None when no line is dark, or when the HV
    clears pull-in plus the spread (dark lines are then the stuck-switch analysis's business).
    """
    v = np.asarray(tap_v, np.float64).ravel()
    _finite("dark_v", dark_v)
    dark = int(np.count_nonzero(v < dark_v))
    if v.size == 0 or dark == 0:
        return None
    low = hv_margin_problem(hv_v, pull_in_v, spread_v)
    if low is None:
        return None
    return f"{dark} of {v.size} self-test lines dark on the emission monitor: {low}"


def _finite(name: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"selftest analysis: {name} must be a finite number, got {value!r}")
