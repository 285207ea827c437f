"""USB faults on the simulated bus: timeouts, stalls and disconnects, as pyusb reports them, for a
number of transfers or until cleared, in-process and across the socket bridge."""

import errno

import pytest
import usb.core

from drivers.digitizer import protocol as dig_p
from lidard.config import load_config
from sim_devices.bench.bench import Bench
from sim_devices.usb.backend import backend_from_url
from tests.helpers.sim_bench import SIM_TOML


def _find(backend, dev):
    return usb.core.find(idVendor=dev.spec.vid, idProduct=dev.spec.pid, backend=backend)


def _identify(d) -> bytes:
    """Digitizer IDENTIFY (vendor IN request)."""
    return bytes(d.ctrl_transfer(dig_p.REQTYPE_IN, int(dig_p.Req.IDENTIFY), 0, 0, 64))


def _string0(d) -> bytes:
    """GET_DESCRIPTOR(STRING 0): a standard request every device answers (the AWG here)."""
    return bytes(d.ctrl_transfer(0x80, 0x06, 0x0300, 0, 4))


def test_timeout_for_n_transfers_then_normal(bench):
    dig = _find(bench.usb_backend, bench.digitizer)
    awg = _find(bench.usb_backend, bench.awg)
    bench.inject_fault("usb_timeout", device="digitizer", n=2)
    for _ in range(2):
        with pytest.raises(usb.core.USBTimeoutError):
            _identify(dig)
        assert _string0(awg)                  # the other device is not affected
    assert _identify(dig).startswith(b"lidard-sim,ADC-2CH")


def test_timeout_until_cleared(bench):
    dig = _find(bench.usb_backend, bench.digitizer)
    bench.inject_fault("usb_timeout", device="digitizer")
    for _ in range(5):
        with pytest.raises(usb.core.USBTimeoutError):
            _identify(dig)
    assert bench.clear_faults("usb_timeout") == 1
    assert _identify(dig).startswith(b"lidard-sim")


def test_stall_is_epipe_until_cleared(bench):
    awg = _find(bench.usb_backend, bench.awg)
    bench.inject_fault("usb_stall", device="awg")
    for _ in range(3):
        with pytest.raises(usb.core.USBError) as info:
            _string0(awg)
        assert info.value.errno == errno.EPIPE and not isinstance(info.value, usb.core.USBTimeoutError)
    bench.clear_faults("usb_stall")
    assert _string0(awg) == b"\x04\x03\x09\x04"


def test_disconnect_leaves_the_bus_until_cleared(bench):
    dig = _find(bench.usb_backend, bench.digitizer)
    bench.inject_fault("usb_disconnect", device="digitizer")
    with pytest.raises(usb.core.USBError) as info:
        _identify(dig)
    assert info.value.errno == errno.ENODEV
    assert _find(bench.usb_backend, bench.digitizer) is None      # a re-find fails meanwhile
    assert _find(bench.usb_backend, bench.awg) is not None
    bench.clear_faults("usb_disconnect")
    again = _find(bench.usb_backend, bench.digitizer)
    assert again is not None and _identify(again).startswith(b"lidard-sim")


def test_disconnect_for_n_transfers_comes_back_by_itself(bench):
    awg = _find(bench.usb_backend, bench.awg)
    bench.inject_fault("usb_disconnect", device="awg", n=3)
    for _ in range(3):
        assert _find(bench.usb_backend, bench.awg) is None
        with pytest.raises(usb.core.USBError) as info:
            _string0(awg)
        assert info.value.errno == errno.ENODEV
    assert _find(bench.usb_backend, bench.awg) is not None and _string0(awg)
    assert bench.active_faults() == []


def test_disconnect_across_the_socket_bridge():
    b = Bench(load_config(SIM_TOML))
    ep = b.start(usb="tcp")
    try:
        backend = backend_from_url(ep["usb_url"])
        dig = _find(backend, b.digitizer)
        assert _identify(dig)
        b.inject_fault("usb_disconnect", device="digitizer")
        assert _find(backend, b.digitizer) is None
        with pytest.raises(usb.core.USBError) as info:
            _identify(dig)
        assert info.value.errno == errno.ENODEV
        b.inject_fault("usb_timeout", device="awg", n=1)
        with pytest.raises(usb.core.USBTimeoutError):
            _string0(_find(backend, b.awg))
        b.clear_faults()
        assert _identify(_find(backend, b.digitizer)).startswith(b"lidard-sim")
        backend.close()
    finally:
        b.close()


def test_replug_resets_the_usb_session_but_keeps_the_settings(bench):
    dig = _find(bench.usb_backend, bench.digitizer)
    dig.ctrl_transfer(dig_p.REQTYPE_OUT, int(dig_p.Req.SET_SEGMENTS), 0, 0, dig_p.enc_u32(7))
    dig.ctrl_transfer(dig_p.REQTYPE_OUT, int(dig_p.Req.ARM), 0, 0, b"")
    assert bench.digitizer.state == dig_p.State.ARMED
    bench.inject_fault("usb_disconnect", device="digitizer")
    bench.clear_faults("usb_disconnect")
    again = _find(bench.usb_backend, bench.digitizer)
    status = dig_p.decode_status(bytes(again.ctrl_transfer(
        dig_p.REQTYPE_IN, int(dig_p.Req.GET_STATUS), 0, 0, 16)))
    assert status.state == dig_p.State.IDLE            # the armed acquisition did not survive
    cfg = dig_p.decode_config(bytes(again.ctrl_transfer(
        dig_p.REQTYPE_IN, int(dig_p.Req.GET_CONFIG), 0, 0, dig_p.CONFIG_LEN)))
    assert cfg.segments == 7                           # the configuration did
    # and a setting is accepted again (it is refused while armed)
    again.ctrl_transfer(dig_p.REQTYPE_OUT, int(dig_p.Req.SET_SEGMENTS), 0, 0, dig_p.enc_u32(9))
    assert bench.digitizer.config.segments == 9
