"""Shared set-up for the fault-injection tests: a started bench (in-process USB) and real drivers
on it. The ``bench`` fixture lives in tests/sim_devices/faults/conftest.py and uses :func:`started_bench`."""

import contextlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from drivers.awg import protocol as awg_p
from drivers.controller.driver import LaserHvController, SettleCheck
from drivers.controller.protocol import Limits
from drivers.fpsa.driver import FpsaController, FpsaLink
from lidard.config import load_config
from lidard.physics.chirp import triangle_drive_v
from sim_devices.bench.bench import Bench

SIM_TOML = Path(__file__).resolve().parents[2] / "config" / "sim.toml"
LIMITS = Limits(max_laser_current_ma=150.0, max_hv_v=60.0, tec_range_c=(15.0, 40.0))


@contextlib.contextmanager
def started_bench() -> Iterator[Bench]:
    b = Bench(load_config(SIM_TOML))
    b.start(usb="inproc")
    try:
        yield b
    finally:
        b.close()


@contextlib.contextmanager
def lit_bench(environ: dict, pixels, scene=None, *, triggers_per_pixel: int = 2) -> Iterator[Bench]:
    """A started bench (``environ`` over config/sim.toml, ``scene`` or its configured one) with the laser
    and HV up, a plain triangle on the AWG and a run over ``pixels`` started: ready to ``capture``."""
    b = Bench(load_config(SIM_TOML, environ=environ), scene)
    b.start(usb="inproc")
    try:
        power_up(b)
        chirp_on(b)
        fp = fpsa(b)
        fp.reset()
        run_pattern(fp, pixels, triggers_per_pixel=triggers_per_pixel)
        yield b
    finally:
        b.close()


def controller(bench: Bench, **kw) -> LaserHvController:
    ep = bench.endpoints()
    kw.setdefault("timeout_s", 1.0)
    return LaserHvController(ep["controller_host"], ep["controller_port"], limits=LIMITS,
                             settle_check=SettleCheck(sleep=bench.clock.advance), **kw)


def fpsa(bench: Bench, **link) -> FpsaController:
    """The bench's FPSA driver; ``link``: fields of its :class:`~drivers.fpsa.link.FpsaLink`."""
    return FpsaController.from_url(bench.endpoints()["fpsa_url"], link=FpsaLink(**link))


def power_up(bench: Bench) -> LaserHvController:
    ctl = controller(bench)
    ctl.bring_up(100.0, 50.0)
    return ctl


def chirp_on(bench: Bench, fs_hz: float = 100e6) -> None:
    """Put a plain triangle on the simulated AWG's output (bench-side set-up, not a fault)."""
    cfg = bench.cfg
    drive = triangle_drive_v(cfg.chirp.excursion_hz, cfg.chirp.ramp_s, fs_hz,
                             bench.laser_preset.static_tuning_hz_per_v)
    amp = float(np.abs(drive).max())
    bench.awg.codes = awg_p.codes_from_normalized(drive / amp)
    bench.awg.amplitude_v = amp
    bench.awg.sample_rate_hz = fs_hz
    bench.awg.output_on = True


def run_pattern(fp: FpsaController, pixels, *, triggers_per_pixel: int = 1,
                trigger_period_ns: int = 200_000, settle_ns: int = 20_000) -> None:
    """Upload ``pixels`` and start a run (settled switches: 20 us >> the 2.7 us column response)."""
    fp.upload_pattern(np.asarray(pixels, dtype=np.int64))
    fp.set_timing(settle_ns=settle_ns, dwell_ns=0, triggers_per_pixel=triggers_per_pixel,
                  trigger_period_ns=trigger_period_ns)
    fp.arm()
    fp.start()


def restart(fp: FpsaController) -> None:
    fp.stop()
    fp.arm()
    fp.start()


def pane_before_wall(z0_m: float, dz_m: float) -> dict:
    """A scene: a half-transmitting pane at ``z0_m`` in front of a retro-reflective wall ``dz_m`` behind
    it (two returns per pixel, ``dz_m`` apart)."""
    return {"target": [
        {"kind": "plane", "point": [0, 0, z0_m], "normal": [0, 0, -1], "reflectivity": 0.5, "transmission": 0.5},
        {"kind": "plane", "point": [0, 0, z0_m + dz_m], "normal": [0, 0, -1], "reflectivity": 2.0}]}


@contextlib.contextmanager
def cal_letters_instrument() -> Iterator:
    """The instrument on an embedded bench (config/sim.toml, the CAL letters), closed after."""
    from lidard.instrument import open_instrument
    inst = open_instrument(load_config("config/sim.toml"), scene_path="config/scenes/cal_letters.toml",
                           bench="embedded")
    try:
        yield inst
    finally:
        inst.close()


@contextlib.contextmanager
def linearized_embedded_instrument() -> Iterator[tuple]:
    """The instrument on an embedded bench (config/sim.toml, an empty scene), linearized once:
    ``(instrument, bench, calibration)``."""
    from lidard.instrument import open_instrument
    inst = open_instrument(load_config("config/sim.toml"), scene_path="config/scenes/empty.toml", bench="embedded")
    try:
        cal = inst.linearize()
        yield inst, inst._on_close.__self__, cal
    finally:
        inst.close()
