"""What reaches the AWG: never a drive beyond its output range, and any drive within it loads
whatever was loaded before (docs/protocols/awg.md: |offset| + amplitude <= 5 V)."""

from __future__ import annotations

import numpy as np
import pytest

from lidard.config import CONFIG_DIR, load_config
from lidard.instrument import InstrumentError, open_instrument

AWG_OUTPUT_MAX_V = 5.0      # docs/protocols/awg.md; the default of devices.awg.max_output_v


@pytest.fixture(scope="module")
def inst():
    i = open_instrument(load_config(CONFIG_DIR / "sim.toml"), bench="embedded")
    yield i
    i.close()


def _triangle(lo_v: float, hi_v: float, n: int = 16000) -> np.ndarray:
    x = np.abs(np.linspace(-1.0, 1.0, n, endpoint=False))
    return lo_v + (hi_v - lo_v) * (1.0 - x)


def test_a_drive_beyond_the_awg_range_is_refused_before_anything_is_sent(inst):
    bench = inst._on_close.__self__
    inst._load_drive(_triangle(-1.0, 1.0))
    before = (bench.awg.amplitude_v, bench.awg.offset_v, bench.awg.drive_volts()[0].copy())
    for bad in (_triangle(-1.0, 103.4), _triangle(-5.2, 0.0), np.full(16000, np.nan), np.zeros((2, 8))):
        with pytest.raises(InstrumentError, match=r"awg: refusing drive .*5 V"):
            inst._load_drive(bad)
        assert bench.awg.amplitude_v == before[0] and bench.awg.offset_v == before[1]
        assert np.array_equal(bench.awg.drive_volts()[0], before[2])


def test_any_drive_within_the_range_loads_after_any_other(inst):
    """amplitude 2.25 V at offset +2.25 V, then 4.9 V at 0 V: setting the new amplitude while the old
    offset stands would ask for 7.15 V (SCPI -222) although both drives fit."""
    bench = inst._on_close.__self__
    for lo, hi in ((0.0, 4.5), (-4.9, 4.9), (-AWG_OUTPUT_MAX_V, 0.2), (-0.2, AWG_OUTPUT_MAX_V), (-1.0, 1.0)):
        d = _triangle(lo, hi)
        inst._load_drive(d)
        got = bench.awg.drive_volts()[0]
        assert got.shape == d.shape
        assert np.max(np.abs(got - d)) <= 2 * (hi - lo) / 65534 + 1e-9      # 16-bit codes
        assert abs(bench.awg.offset_v) + bench.awg.amplitude_v <= AWG_OUTPUT_MAX_V + 1e-9


def test_the_drive_limit_follows_the_configuration(inst, monkeypatch):
    assert inst.cfg.devices.awg.max_output_v == AWG_OUTPUT_MAX_V
    d = inst.cfg.devices
    lower = d.model_copy(update={"awg": d.awg.model_copy(update={"max_output_v": 2.0})})
    # the acquisition lifecycle loads drives with its configuration
    monkeypatch.setattr(inst.acquisition, "cfg", inst.cfg.model_copy(update={"devices": lower}))
    with pytest.raises(InstrumentError, match=r"\+-2 V \(devices.awg.max_output_v\)"):
        inst._load_drive(_triangle(-1.0, 2.5))
