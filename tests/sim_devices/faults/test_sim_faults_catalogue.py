"""Fault catalogue: validation, Bench bookkeeping, the control socket, [[sim.faults]] in the config,
the virtual clock's timers and the serial line-noise statistics."""

import json
from pathlib import Path

import numpy as np
import pytest

from lidard.config import load_config
from lidard.errors import ConfigError
from sim_devices.bench.bench import Bench, BenchControlClient
from sim_devices.clock import VirtualClock
from sim_devices.faults import FAULT_KINDS, SerialLineNoise, validate_fault
from tests.helpers.sim_bench import SIM_TOML


@pytest.mark.parametrize("kind, params, names", [
    ("serial_dorp", {"rate": 0.1}, "serial_dorp"),
    ("serial_drop", {}, "'rate' is required"),
    ("serial_drop", {"rate": 1.5}, "rate"),
    ("serial_flip", {"rate": "often"}, "rate"),
    ("serial_flip", {"rate": 0.1, "burst": 3}, "'burst'"),
    ("usb_timeout", {"device": "scope"}, "device"),
    ("usb_stall", {"device": "awg", "n": 0}, "n must be >= 1"),
    ("usb_disconnect", {"device": "awg", "n": 1.5}, "n must be an integer"),
    ("modbus_exception", {"code": 7}, "code"),
    ("modbus_exception", {"n": 2}, "'code' is required"),
    ("interlock_open", {"at_s": 1.0, "after_segments": 3}, "not both"),
    ("interlock_open", {"at_s": float("nan")}, "at_s"),
    ("stuck_switch", {"line": "diag", "index": 1, "state": "on"}, "line"),
    ("stuck_switch", {"line": "row", "index": -1, "state": "on"}, "index"),
    ("stuck_switch", {"line": "row", "index": 1, "state": True}, "state"),
    ("digitizer_overrange", {"gain": 0}, "gain"),
    ("serial_disconnect", {"reconnect_after_s": -1}, "reconnect_after_s"),
    ("hv_fault", {"volts": 0}, "'volts'"),
])
def test_bad_faults_are_value_errors_naming_the_problem(kind, params, names):
    with pytest.raises(ValueError, match=names.replace("(", r"\(")):
        validate_fault(kind, params)


def test_defaults_are_filled_in():
    assert validate_fault("usb_timeout", {"device": "digitizer"}) == {
        "kind": "usb_timeout", "device": "digitizer", "n": None}
    assert validate_fault("interlock_open") == {"kind": "interlock_open", "at_s": None,
                                                "after_segments": None}
    assert validate_fault("digitizer_overrange")["gain"] > 1


def test_bench_bookkeeping_ids_replace_and_clear(bench):
    a = bench.inject_fault("serial_flip", rate=0.01)
    b = bench.inject_fault("stuck_switch", line="col", index=7, state="off")
    assert a["id"] != b["id"] and a["kind"] == "serial_flip" and a["rate"] == 0.01
    # a singleton kind injected again replaces the first
    c = bench.inject_fault("serial_flip", rate=0.02)
    kinds = sorted(f["kind"] for f in bench.active_faults())
    assert kinds == ["serial_flip", "stuck_switch"]
    assert [f["rate"] for f in bench.active_faults() if f["kind"] == "serial_flip"] == [0.02]
    assert c["id"] not in (a["id"], b["id"])
    assert bench.serial_line.flip_rate == 0.02
    assert bench.clear_faults("serial_flip") == 1
    assert bench.serial_line.flip_rate == 0.0
    assert bench.clear_faults() == 1
    assert bench.active_faults() == []
    with pytest.raises(ValueError, match="unknown fault kind"):
        bench.clear_faults("gremlins")


def test_a_rejected_fault_changes_nothing(bench):
    with pytest.raises(ValueError, match="index must be 0..127"):
        bench.inject_fault("stuck_switch", line="row", index=128, state="on")
    with pytest.raises(ValueError, match="unknown fault kind"):
        bench.inject_fault("meteor")
    assert bench.active_faults() == [] and bench.fpga.stuck_switches == []


def test_count_limited_faults_leave_the_list_once_used(bench):
    import usb.core

    bench.inject_fault("usb_timeout", device="awg", n=1)
    assert [f["kind"] for f in bench.active_faults()] == ["usb_timeout"]
    dev = usb.core.find(idVendor=bench.awg.spec.vid, idProduct=bench.awg.spec.pid,
                        backend=bench.usb_backend)
    with pytest.raises(usb.core.USBTimeoutError):
        dev.ctrl_transfer(0x80, 0x06, 0x0300, 0, 4)   # GET_DESCRIPTOR(string 0)
    assert bench.active_faults() == []


def test_control_socket_inject_list_clear():
    b = Bench(load_config(SIM_TOML))
    b.start(usb="inproc", control=True)
    try:
        cli = BenchControlClient(b.endpoints()["control_port"])
        got = cli.call("inject", kind="stuck_switch", line="row", index=4, state="on")
        assert got["fault"]["kind"] == "stuck_switch" and isinstance(got["fault"]["id"], int)
        assert b.fpga.stuck_switches == [("row", 4, True)]
        listed = cli.call("faults")["faults"]
        assert [f["id"] for f in listed] == [got["fault"]["id"]]
        json.dumps(listed)  # everything in a fault record is JSON
        with pytest.raises(ValueError, match="rate"):
            cli.call("inject", kind="serial_drop", rate=2)
        assert cli.call("clear_faults", kind="stuck_switch") == {"cleared": 1}
        assert b.fpga.stuck_switches == [] and cli.call("faults") == {"faults": []}
        cli.close()
    finally:
        b.close()


def _write(tmp_path, body: str) -> Path:
    p = tmp_path / "faulty.toml"
    p.write_text(SIM_TOML.read_text() + body)
    return p


def test_config_faults_are_validated_naming_the_entry(tmp_path):
    p = _write(tmp_path, '\n[[sim.faults]]\nkind = "serial_flip"\nrate = 0.01\n'
                         '\n[[sim.faults]]\nkind = "stuck_switch"\nline = "row"\nindex = 2\n')
    cfg = load_config(p)      # the daemon side checks only the shape; the simulator owns the catalogue
    with pytest.raises(ConfigError, match=r"sim\.faults.*entry 1.*stuck_switch.*'state' is required"):
        Bench(cfg)


def test_config_fault_without_a_kind_is_refused_at_load(tmp_path):
    p = _write(tmp_path, '\n[[sim.faults]]\nrate = 0.01\n')
    with pytest.raises(ConfigError, match=r"sim\.faults.*entry 0.*kind"):
        load_config(p)


def test_config_faults_are_applied_at_start(tmp_path):
    p = _write(tmp_path, '\n[[sim.faults]]\nkind = "serial_flip"\nrate = 0.01\n'
                         '\n[[sim.faults]]\nkind = "stuck_switch"\nline = "col"\nindex = 9\nstate = "on"\n')
    b = Bench(load_config(p))
    try:
        assert b.active_faults() == []          # nothing before start
        b.start(usb="inproc")
        assert sorted(f["kind"] for f in b.active_faults()) == ["serial_flip", "stuck_switch"]
        assert b.serial_line.flip_rate == 0.01 and b.fpga.stuck_switches == [("col", 9, True)]
    finally:
        b.close()


def test_every_catalogue_kind_can_be_injected_and_cleared(bench):
    params = {"serial_drop": {"rate": 0.1}, "serial_flip": {"rate": 0.1},
              "usb_timeout": {"device": "awg"}, "usb_stall": {"device": "digitizer"},
              "usb_disconnect": {"device": "awg"}, "modbus_exception": {"code": 6},
              "stuck_switch": {"line": "row", "index": 0, "state": "off"}, "tec_offset": {"offset_c": 0.2}}
    for kind in FAULT_KINDS:
        bench.inject_fault(kind, **params.get(kind, {}))
    assert sorted(f["kind"] for f in bench.active_faults()) == sorted(FAULT_KINDS)
    assert bench.clear_faults() == len(FAULT_KINDS)
    assert bench.active_faults() == []
    # normal behaviour is back everywhere
    assert not bench.serial_line.active and bench.awg.connected and bench.digitizer.connected
    assert bench.controller.state.interlock_closed and bench.fpga.stuck_switches == []
    assert bench.controller.model.tec_offset_c == 0.0
    assert Path(bench.endpoints()["fpsa_url"]).exists()


def test_clock_timers_fire_in_order_once_and_can_be_cancelled():
    clock = VirtualClock()
    fired = []
    clock.call_at(2.0, lambda: fired.append(("b", clock.now())))
    clock.call_at(1.0, lambda: fired.append(("a", clock.now())))
    h = clock.call_at(1.5, lambda: fired.append(("x", clock.now())))
    clock.cancel(h)
    clock.advance(0.9)
    assert fired == []
    clock.advance_to(3.0)
    assert [f[0] for f in fired] == ["a", "b"] and all(t == 3.0 for _, t in fired)
    clock.advance(1.0)
    assert len(fired) == 2 and clock.pending_timers() == 0
    clock.call_at(0.0, lambda: fired.append(("now", clock.now())))  # already due: runs at once
    assert fired[-1] == ("now", 4.0)


def test_serial_line_noise_rates_and_single_bit_flips():
    n = 200_000
    data = bytes(np.random.default_rng(3).integers(0, 256, n, dtype=np.uint8))
    drop = SerialLineNoise(seed=11)
    drop.drop_rate = 0.02
    out = drop.apply(data)
    # binomial: mean 4000, sd 63; 6 sd bounds
    assert abs((n - len(out)) - 0.02 * n) < 6 * np.sqrt(n * 0.02 * 0.98)
    assert drop.bytes_dropped == n - len(out)
    flip = SerialLineNoise(seed=12)
    flip.flip_rate = 0.05
    got = np.frombuffer(flip.apply(data), np.uint8)
    diff = got ^ np.frombuffer(data, np.uint8)
    changed = diff != 0
    assert abs(changed.sum() - 0.05 * n) < 6 * np.sqrt(n * 0.05 * 0.95)
    # exactly one bit per affected byte, every bit position used
    assert np.all(np.unpackbits(diff[changed, None], axis=1).sum(axis=1) == 1)
    assert set(np.log2(diff[changed]).astype(int)) == set(range(8))
    # seeded: the same seed corrupts the same bytes
    again = SerialLineNoise(seed=12)
    again.flip_rate = 0.05
    assert again.apply(data) == got.tobytes()
    # rate 0: untouched
    assert SerialLineNoise(seed=1).apply(data) == data
