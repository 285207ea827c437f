"""The FPSA board below the firmware: two HV583 converters, their wiring to the switch lines, the
drive log and the switches that ignore their drive (§4.3.3 and Fig. 4-22; §4.2.1; §4.2.6).

:class:`FpsaBoard` is what the firmware (``sim_devices.fpsa.firmware``) commands and what the chip
optics (``sim_devices.fpsa.beams``) read: the HV583 registers (powering up RANDOM), which bonded row
and which column lines are driven high, every line change as a drive event at the voltage the
supply gives (with the hold-level drive after each pull-in boost), and the stuck-switch intervals of
fault injection. Its ``revision`` counts the changes of the drive log and of the stuck switches: the
optics rebuild their switch banks only when it moved.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim_devices.fpsa.drive_log import (
    COL,
    ROW,
    DriveEvents,
    StuckSwitches,
    lines_high_before,
    settle_horizon_s,
)
from sim_devices.fpsa.hv583 import HV583, default_bonded_rows
from sim_devices.fpsa.hv_drive import HOLD_BOOST_S, HvDrive
from sim_devices.world.mems import COLUMN_SWITCH, ROW_SWITCH, SwitchDynamics


@dataclass(frozen=True)
class FpgaConfig:
    rows: int = 128
    cols: int = 128
    bonded_rows: tuple[int, ...] | None = None  # None: default_bonded_rows(rows)
    baudrate: int = 3_000_000
    hv_supply_v: float = 40.0  # above the 32 V pull-in of §4.2.6
    seed: int = 0  # power-up register contents
    vendor: str = "lidard-sim"
    model: str = "FPSA128-HV583"
    firmware: tuple[int, int, int] = (1, 0, 0)
    row_dynamics: SwitchDynamics = ROW_SWITCH
    col_dynamics: SwitchDynamics = COLUMN_SWITCH
    beam_floor: float = 1e-6  # beams dimmer than this (path transmission) are not reported
    threshold_spread_v: float = 0.0  # 1-sigma switch-to-switch spread of pull-in/release (seeded)
    min_trigger_period_ns: int = 100

    def __post_init__(self) -> None:
        if not (1 <= self.rows <= HV583.N_OUTPUTS and 1 <= self.cols <= HV583.N_OUTPUTS):
            raise ValueError(f"rows/cols must be 1..128 (one HV583 each), got {self.rows}x{self.cols}")
        if not self.baudrate > 0:
            raise ValueError(f"baudrate must be > 0, got {self.baudrate!r}")

    @property
    def bonded(self) -> tuple[int, ...]:
        b = default_bonded_rows(self.rows) if self.bonded_rows is None else tuple(self.bonded_rows)
        if any(not 0 <= r < self.rows for r in b):
            raise ValueError(f"bonded_rows must lie in 0..{self.rows - 1}")
        return tuple(sorted(set(b)))


class FpsaBoard:
    """HV583 registers, line wiring, drive log and stuck switches of the simulated FPSA board.

    ``supply()`` is what the HV583 outputs carry (the bench points the FPGA's ``supply`` at the
    controller's HV output). Not thread-safe on its own: the FPGA simulator calls it under its lock."""

    def __init__(self, config: FpgaConfig, supply: Callable[[], HvDrive]) -> None:
        self.config = config
        self.supply = supply
        self.bonded = config.bonded
        self.bonded_mask = np.zeros(config.rows, bool)
        self.bonded_mask[list(self.bonded)] = True
        self.events = DriveEvents()
        self.holds = DriveEvents()  # hold-level drive after each pull-in boost (sim_devices.fpsa.hv_drive)
        # intervals in which a switch ignores its drive (fault injection)
        self.stuck = StuckSwitches()
        # a line's drive history older than this (before its last switch-off) is dropped at each START
        self.settle_horizon_s = settle_horizon_s(config.row_dynamics, config.col_dynamics)
        self.revision = 0
        rng = np.random.default_rng(config.seed)
        self.hv_rows = HV583(rng)
        self.hv_cols = HV583(rng)
        self.row_high = np.zeros(config.rows, bool)
        self.col_high = np.zeros(config.cols, bool)

    def touch(self) -> None:
        """The drive log or the stuck switches changed: the switch banks built from them are stale."""
        self.revision += 1

    def power_up(self, t_s: float) -> bool:
        """Registers with their RANDOM power-up contents (seeded); logs the lines they drive at
        ``t_s``. Returns whether more than one bonded row is on (the firmware flags MULTI_ROW)."""
        rng = np.random.default_rng(self.config.seed)
        self.hv_rows = HV583(rng)
        self.hv_cols = HV583(rng)
        multi_row = bool(self.bonded_lines(self.hv_rows.outputs).sum() > 1)
        self.row_high = np.zeros(self.config.rows, bool)
        self.col_high = np.zeros(self.config.cols, bool)
        self.apply_outputs(t_s)
        return multi_row

    def bonded_lines(self, outputs: np.ndarray) -> np.ndarray:
        return outputs[: self.config.rows] & self.bonded_mask

    def apply_outputs(self, t_s: float) -> None:
        """Log drive events for every wired line whose HV583 output changed at ``t_s``."""
        rows = self.bonded_lines(self.hv_rows.outputs)
        cols = self.hv_cols.outputs[: self.config.cols]
        drive = self.supply()
        for kind, new, old in ((ROW, rows, self.row_high), (COL, cols, self.col_high)):
            changed = np.flatnonzero(new != old)
            if changed.size:
                self.events.add(kind, changed, t_s, np.where(new[changed], drive.hv_v, 0.0))
                rising = changed[new[changed]]
                if drive.holds and rising.size:
                    self.holds.add(kind, rising, t_s + HOLD_BOOST_S, drive.hold_v)
        self.row_high, self.col_high = rows.copy(), cols.copy()
        self.touch()

    def load_lines(self, t_s: float, row: int | None, col: int | None) -> float:
        """Shift one row bit and one column bit (never two rows), latch. Returns the latch time
        (t_s + 0.8 us)."""
        want_r = np.zeros(HV583.N_OUTPUTS, bool)
        want_c = np.zeros(HV583.N_OUTPUTS, bool)
        if row is not None:
            want_r[row] = True
        if col is not None:
            want_c[col] = True
        self.hv_rows.shift_in(want_r)
        self.hv_cols.shift_in(want_c)
        t_latch = t_s + HV583.refresh_s()
        self.hv_rows.latch_enable()
        self.hv_cols.latch_enable()
        self.apply_outputs(t_latch)
        return t_latch

    def clear_registers(self) -> None:
        """After a run the firmware leaves the registers cleared (the drive log already holds the
        lines-off events at the run's end)."""
        for hv in (self.hv_rows, self.hv_cols):
            hv.shift[:] = False
            hv.latch[:] = False
        self.row_high[:] = False
        self.col_high[:] = False

    def lines_high_before(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Row and column lines driven high by the drive events strictly before ``t_s``."""
        return lines_high_before(self.events, self.config.rows, self.config.cols, t_s)
