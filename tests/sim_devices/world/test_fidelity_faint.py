"""Faint returns (sim_devices.world.fidelity, issue 18 item 3): a return at the skipping bound moves
every DFT bin of its record by at most 1 % of that bin's noise std, measured on synthesized records;
without receiver noise nothing is skipped; the bench skips the FPSA's leak beams of a 1-average scan
and says so in the ledger."""

from __future__ import annotations

import math
import threading

import numpy as np

from lidard.config import CONFIG_DIR, load_config, load_laser
from lidard.instrument import ScanRequest, open_instrument
from sim_devices.world.fidelity import FAINT_BIN_FRACTION, faint_returns
from sim_devices.world.laser import DfbLaser, triangle_drive
from sim_devices.world.synth import AdcSpec, HitBatch, synthesize, trajectory
from tests.helpers.tolerances import NOMINAL_ENV

FS = 40e6
N = 3200
ASD = 2e-8


def test_a_return_at_the_bound_moves_no_bin_by_more_than_its_fraction_of_the_noise():
    laser = DfbLaser(load_laser("ideal"))
    traj = trajectory(laser, triangle_drive(8.6e9, 80e-6, 100e6, laser.static_tuning_hz_per_v), 100e6)
    adc = AdcSpec(FS, N, bits=16, input_range_v=1.0, quantize=False)
    sigma = ASD * math.sqrt(FS / 2.0)
    a_bound = 2.0 * FAINT_BIN_FRACTION * sigma / math.sqrt(N)
    assert faint_returns([a_bound * 0.999], ASD, FS, N)[0] and not faint_returns([a_bound * 1.001], ASD, FS, N)[0]
    n_seg = 64
    seg = np.arange(n_seg)
    hits = HitBatch.from_targets(seg, np.linspace(0.5, 1.9, n_seg), a_bound)
    with_ret = synthesize(traj, adc, np.zeros(n_seg), hits, noise_asd_v_per_rthz=ASD, rng=np.random.default_rng(5))
    without = synthesize(traj, adc, np.zeros(n_seg), None, noise_asd_v_per_rthz=ASD, rng=np.random.default_rng(5))
    moved = np.abs(np.fft.rfft(with_ret.beat - without.beat, axis=1))[:, 1:-1]   # the same noise draws
    bin_noise_std = np.sqrt(np.mean(np.abs(np.fft.rfft(without.beat, axis=1))[:, 1:-1] ** 2))
    assert abs(bin_noise_std / (sigma * math.sqrt(N)) - 1.0) < 0.05           # the bin noise is sigma sqrt(N)
    assert moved.max() <= FAINT_BIN_FRACTION * bin_noise_std * 1.05
    assert moved.max() > 0.5 * FAINT_BIN_FRACTION * bin_noise_std            # the bound is tight, not vacuous


def test_nothing_is_faint_without_noise():
    assert not faint_returns([1e-12, 0.0], 0.0, FS, N).any()


def test_the_bench_skips_leak_beams_and_keeps_the_returns():
    cfg = load_config(CONFIG_DIR / "sim.toml", environ=NOMINAL_ENV)
    inst = open_instrument(cfg, scene_path=str(CONFIG_DIR / "scenes" / "cal_letters.toml"), bench="embedded")
    try:
        cal = inst.linearize()
        req = ScanRequest(pattern="roi", rows=(40, 42), cols=(40, 56), averages=1, max_range_m=2.0)
        res = inst.run_scan(req, lambda p: None, threading.Event(), cal)
    finally:
        inst.close()
    led = res.meta["sim"]["fidelity"]
    assert led["skipped"].get("faint_returns", 0) > 0 and "faint_returns" in led["rules"]
    assert len(res.points) >= res.pixels_scanned         # every pixel still gives its return
