"""The HV583 high-voltage serial-to-parallel converter of the FPSA board, and the board's row bonding
(§4.3.3 and Fig. 4-22).

Two of these drive the 128x128 switch array (converter A: rows, converter B: columns). Each has four
32-bit shift registers clocked in parallel at 40 MHz, a latch, blanking and polarity: loading all
128 outputs takes 32 clocks = 0.8 us, the 1.25 MHz full-refresh rate of §4.3.3. Registers and
latches power up with random contents (the caller's seeded generator), so the array shows garbage
until the firmware clears them. Used by :mod:`sim_devices.fpsa.device` and its command handlers.
"""

from __future__ import annotations

import numpy as np


class HV583:
    """One HV583: 128 HV outputs fed by four 32-bit shift registers clocked in parallel.

    Register k, bit j drives output ``32 k + j`` after the latch-enable pulse. Data enters each
    register at bit 0 and moves one bit up per clock, so the bit clocked first ends up at bit 31.
    ``blank`` forces every output low; ``polarity_inverted`` inverts all outputs.
    """

    N_OUTPUTS = 128
    N_REGISTERS = 4
    REGISTER_BITS = 32
    MAX_CLOCK_HZ = 40e6

    def __init__(self, rng: np.random.Generator) -> None:
        # Power-up: registers and latches hold whatever the flip-flops settled to.
        self.shift = rng.integers(0, 2, (self.N_REGISTERS, self.REGISTER_BITS)).astype(bool)
        self.latch = rng.integers(0, 2, self.N_OUTPUTS).astype(bool)
        self.blank = False
        self.polarity_inverted = False
        self.clocks = 0

    def clock_in(self, bits: np.ndarray) -> None:
        """One shift clock: ``bits`` (4,) enter bit 0 of the four registers."""
        self.shift[:, 1:] = self.shift[:, :-1].copy()
        self.shift[:, 0] = np.asarray(bits, bool)
        self.clocks += 1

    def shift_in(self, outputs: np.ndarray) -> int:
        """Clock in a full frame so that after :meth:`latch_enable` output o == outputs[o].
        Returns the number of clocks used (32)."""
        want = np.asarray(outputs, bool).reshape(self.N_REGISTERS, self.REGISTER_BITS)
        for j in range(self.REGISTER_BITS - 1, -1, -1):
            self.clock_in(want[:, j])
        return self.REGISTER_BITS

    def latch_enable(self) -> None:
        self.latch = self.shift.reshape(-1).copy()

    @property
    def outputs(self) -> np.ndarray:
        if self.blank:
            return np.zeros(self.N_OUTPUTS, bool)
        return self.latch ^ self.polarity_inverted

    @classmethod
    def refresh_s(cls) -> float:
        """Time to reload every output: 32 clocks at 40 MHz = 0.8 us (1.25 MHz refresh)."""
        return cls.REGISTER_BITS / cls.MAX_CLOCK_HZ


def default_bonded_rows(rows: int = 128) -> tuple[int, ...]:
    """§4.3.3: "one signal in every four rows skipped" -> rows with r % 4 == 3 not bonded."""
    return tuple(r for r in range(rows) if r % 4 != 3)
