"""A simulated bench that cannot start says why, through the daemon's error (not just "did not start")."""

from pathlib import Path

import pytest

from lidard.config import load_config
from lidard.instrument import InstrumentError, open_instrument

ROOT = Path(__file__).resolve().parents[2]


def test_child_bench_refusing_a_fault_entry_names_it(tmp_path):
    text = (ROOT / "config" / "sim.toml").read_text().replace(
        '"scenes/cal_letters.toml"', repr(str(ROOT / "config" / "scenes" / "cal_letters.toml")).replace("'", '"'))
    text += '\n[[sim.faults]]\nkind = "stuck_switch"\nline = "row"\nindex = 2\n'
    p = tmp_path / "bad_fault.toml"
    p.write_text(text)
    cfg = load_config(p)              # the shape is fine; the simulator's catalogue refuses the entry
    with pytest.raises(InstrumentError, match=r"did not start: .*sim\.faults: entry 0: .*'state' is required"):
        open_instrument(cfg, bench="child")
