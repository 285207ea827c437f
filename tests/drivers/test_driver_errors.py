"""The one driver exception tree (drivers/errors.py): every class is in it, every error names its
device and command, and the per-device names are the shared classes or subclasses of them."""

import importlib
import inspect
import pickle
import pkgutil

import pytest

import drivers
from drivers import errors as e
from drivers.controller import errors as ce
from drivers.controller import protocol as cp
from drivers.digitizer import protocol as dp
from drivers.fpsa import errors as fe
from drivers.fpsa import protocol as fp
from drivers.transport import errors as te
from drivers import usbtmc


def _driver_modules():
    for info in pkgutil.walk_packages(drivers.__path__, "drivers."):
        yield importlib.import_module(info.name)


def test_every_exception_class_in_drivers_is_a_device_error():
    found = []
    for mod in _driver_modules():
        for name, obj in vars(mod).items():
            if inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == mod.__name__:
                found.append(obj)
                assert issubclass(obj, e.DeviceError), f"{mod.__name__}.{name} is outside drivers.errors"
    assert len(found) >= 30  # the walk really saw the per-device modules


def test_there_is_one_device_timeout_whose_device_is_data():
    assert te.DeviceTimeout is usbtmc.DeviceTimeout is ce.DeviceTimeout is e.DeviceTimeout
    assert issubclass(e.DeviceTimeout, TimeoutError)
    assert [e.DeviceTimeout(d, "ARM").device for d in ("fpsa", "digitizer", "controller")] == \
        ["fpsa", "digitizer", "controller"]


def test_there_is_one_protocol_error_whose_device_is_data():
    named = {obj for mod in _driver_modules() for name, obj in vars(mod).items()
             if name == "ProtocolError" and inspect.isclass(obj)}
    assert named == {e.ProtocolError}
    assert not hasattr(fe, "ProtocolError") and not hasattr(usbtmc, "ProtocolError") \
        and not hasattr(ce, "ProtocolError")
    # each device's codec raises it (or a subclass), naming the device
    cases = {"fpsa": lambda: fp.decode_frame(b"\x05\x01\x00"),
             "awg": lambda: usbtmc.decode_header(b"\x00" * 3),
             "digitizer": lambda: dp.decode_segment_header(b"\x00" * 5),
             "controller": lambda: cp.decode_faults(0x20)}
    for device, bad in cases.items():
        with pytest.raises(e.ProtocolError) as ei:
            bad()
        assert ei.value.device == device


def test_codec_errors_name_device_and_command():
    with pytest.raises(e.FramingError) as ei:
        fp.decode_frame(b"\x05\x01\x00")  # COBS block overruns the frame
    assert (ei.value.device, ei.value.command) == ("fpsa", "decode")
    bad_crc = bytearray(fp.encode_inner(7, fp.Cmd.ARM))
    bad_crc[-1] ^= 0xFF
    with pytest.raises(e.CrcError) as ei:
        fp.decode_inner(bytes(bad_crc))
    assert (ei.value.device, ei.value.command, ei.value.seq, ei.value.cmd) == ("fpsa", "ARM", 7, fp.Cmd.ARM)
    with pytest.raises(e.ProtocolError) as ei:
        usbtmc.decode_header(b"\x00" * 3)
    assert (ei.value.device, ei.value.command) == ("awg", "decode")
    with pytest.raises(e.PayloadError) as ei:
        cp.decode_faults(0x20)
    assert (ei.value.device, ei.value.command) == ("controller", "decode FAULTS")


def test_controller_refusals_sit_in_the_shared_tree():
    with pytest.raises(e.InvalidValue) as ei:
        cp.HARDWARE_LIMITS.check(cp.LASER_CURRENT_SETPOINT, 1e9)
    assert ei.value.device == "controller" and "LASER_CURRENT" in ei.value.command
    assert isinstance(ei.value, ValueError)
    err = ce.modbus_exception("write", "HV_ENABLE", 1, 4)
    assert isinstance(err, e.CommandRefused) and (err.device, err.command) == ("controller", "write")
    assert issubclass(ce.InterlockOpen, e.DeviceFaulted) and issubclass(ce.DeviceFaulted, e.DeviceFaulted)
    assert issubclass(ce.DeviceUnreachable, e.DeviceGone)


def test_usb_errors_keep_their_names_and_join_the_tree():
    assert issubclass(usbtmc.DeviceStall, e.CommandRefused)
    assert issubclass(usbtmc.DeviceDisconnected, e.DeviceGone)
    err = usbtmc.DeviceTimeout("digitizer", "ARM", "no answer")
    assert isinstance(err, e.TransportError) and (err.device, err.command) == ("digitizer", "ARM")
    assert str(err) == "digitizer: ARM: no answer"


@pytest.mark.parametrize("err", [
    e.DeviceTimeout("fpsa", "ARM", timeout_s=0.5, attempts=4, url="/dev/x"),
    ce.DeviceFaulted("bring_up", frozenset()),
    usbtmc.DeviceDisconnected("awg", "write", "gone"),
    fe.NakError("fpsa", "ARM", fp.NakCode.BAD_STATE, 1),
])
def test_errors_survive_pickling_with_their_context(err):
    back = pickle.loads(pickle.dumps(err))
    assert type(back) is type(err) and str(back) == str(err)
    assert (back.device, back.command) == (err.device, err.command)


def test_channel_errors_name_device_command_and_url(tmp_path):
    from drivers.transport import open_channel

    with pytest.raises(e.TransportError) as ei:
        open_channel("nosuch://x", device="fpsa")
    assert (ei.value.device, ei.value.command, ei.value.url) == ("fpsa", "open", "nosuch://x")
    missing = str(tmp_path / "no-such-tty")
    with pytest.raises(e.DeviceGone) as ei:  # a port that is not there: gone, not a bad URL
        open_channel(missing, device="fpsa")
    assert ei.value.url == missing and isinstance(ei.value, ConnectionError)
