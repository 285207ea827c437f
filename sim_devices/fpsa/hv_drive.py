"""The HV that reaches the HV583 outputs: the controller's supply, and the pull-in/hold drive option.

The HV583 switches its outputs between 0 V and its supply rail (VPP), which is the controller's HV
output (Modbus HV_SETPOINT, gated by HV_ENABLE): a line driven high carries whatever the controller
delivers, so an HV below a switch's pull-in voltage cannot actuate it (§4.2.6, Fig. 4-15a), and an
HV between release and pull-in holds the switches already on and pulls in no new ones.

Hold drive (controller HV_HOLD_SETPOINT > 0 and below the HV): a line that goes high is driven at
the full HV for ``HOLD_BOOST_S`` (pull-in), then at the hold level. A parallel-plate actuator, once
pulled in, stays down at any voltage above its release voltage, so holding just above release
keeps the switch on with less field across the dielectric (less charging) and, since the actuator
discharges from a lower voltage, a faster release (see :mod:`sim_devices.world.mems`).

The supply is sampled when the FPGA latches lines (SET_PIXEL/CLEAR/STOP, and for a whole run at
START, when the run's drive events are computed in closed form): a change of the controller's HV in
the middle of a run acts from the next run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: How long a newly driven line sees the full HV before dropping to the hold level: longer than the
#: slowest switch response of the 128x128 (2.7 us, §4.3.6), so the plate is down before the drop.
HOLD_BOOST_S = 3.0e-6


@dataclass(frozen=True)
class HvDrive:
    """What the HV583 outputs carry: ``hv_v`` while pulling in, ``hold_v`` afterwards (0 = no hold)."""

    hv_v: float
    hold_v: float = 0.0

    @property
    def holds(self) -> bool:
        """The hold option acts only below the HV (a hold at or above it is just the HV)."""
        return 0.0 < self.hold_v < self.hv_v


def valid_holds(lines: np.ndarray, t_s: np.ndarray, volts: np.ndarray,
                hold_lines: np.ndarray, hold_t_s: np.ndarray) -> np.ndarray:
    """Mask of the hold events that still apply: the line's last drive event at or before the
    hold time must be the one that drove it high (a line switched off, or re-driven, before its
    boost ended keeps that later drive). Drive events at equal times keep their given order."""
    if hold_lines.size == 0:
        return np.zeros(0, bool)
    if lines.size == 0:
        return np.zeros(hold_lines.size, bool)
    times = np.sort(t_s)
    stride = np.int64(times.size + 1)
    order = np.lexsort((np.arange(lines.size), t_s, lines))
    key = lines[order] * stride + np.searchsorted(times, t_s[order], side="right")
    q = hold_lines.astype(np.int64) * stride + np.searchsorted(times, hold_t_s, side="right")
    idx = np.searchsorted(key, q, side="right") - 1
    ok = idx >= 0
    i = np.maximum(idx, 0)
    return ok & (lines[order][i] == hold_lines) & (volts[order][i] > 0.0)


__all__ = ["HOLD_BOOST_S", "HvDrive", "valid_holds"]
