"""``--sim``: an embedded simulated bench with the daemon's own worker and store, in this process.

The command runs the same job code as the daemon (lidard.jobs.ScanWorker over lidard.store.Store),
so a one-shot ``lidarctl scan --sim`` and a scan through ``lidard`` write the same files. Without
``--data-dir`` the store is a temporary directory: it starts with the calibration of the same
configuration from the user's cache (lidard.store.calcache), or without one, and then linearizes the chirp
first (ILC, dissertation §2.2) and leaves the result in the cache. ``--no-cal-cache`` skips the cache;
``--data-dir DIR`` keeps calibrations in DIR instead.

Range and pointing calibrations (a scan, ``factory=True``): the temporary store also starts with the
cached records of the bench's set-up (lidard.store.calcache.load_records, keyed by the set-up hash the records
are tied to). With none there (nor in ``--data-dir``), the first scan runs the simulated bench's factory
calibration (lidard.jobs.guided: plates, fit, spheres; through the instruments), says so once on stderr
and keeps the records in the cache (or in ``--data-dir``). ``sim.factory_calibration = false`` or
``--uncalibrated`` skips it.
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

from . import base
from .base import CliError


def sim_config(args):
    """The configuration of ``--sim`` (default: the packaged config/sim.toml), refused if not simulated."""
    from ..config import CONFIG_DIR
    cfg = base.load_config(args.config or str(CONFIG_DIR / "sim.toml"), getattr(args, "profile", None))
    if not cfg.sim.enabled:
        raise CliError(f"--sim needs a simulated configuration; {cfg.source} has sim.enabled = false")
    return cfg


def run_meta(cfg, scene_path: str | None) -> dict:
    """The sidecar's run description: what the daemon's app records, plus the scene on a bench."""
    from ..outputs import scene_identity
    profile = cfg.resolved.profile
    scene = scene_path or str(cfg.resolve_path(cfg.sim.scene))
    return {"profile": profile.name, "lens": cfg.lens or profile.default_lens, "laser": cfg.laser,
            "chirp": cfg.chirp.model_dump(), "adc": cfg.adc.model_dump(),
            "detector": cfg.detector.model_dump(), "config": cfg.source, "scene": scene_identity(scene)}


@contextlib.contextmanager
def embedded(args, cfg=None, scene_path: str | None = None, factory: bool = False, scan=None):
    """Yield ``(worker, store, instrument)``; on exit stop the worker, close the store and the bench.
    ``factory``: calibrate range and pointing before the first scan when nothing of this set-up is stored.
    ``scan``: the ScanRequest the command is about to run: what it needs starts while the command sets
    up (Instrument.expect_scan: the DSP's worker processes if its batches go to them, the bench's
    compiled kernels if it pays for them); without one the scan worker starts the worker processes."""
    from ..instrument.calibration.setup import instrument_setup
    from ..jobs import ScanWorker
    from ..store import Store
    cfg = cfg if cfg is not None else sim_config(args)
    meta = run_meta(cfg, scene_path)
    kw = {"scene_path": scene_path} if scene_path is not None else {}
    tmp = None
    data_dir = args.data_dir
    if data_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="lidarctl-")
        data_dir = tmp.name
    # The store first: it takes the data directory's lock, so a held directory is refused before
    # a bench starts (the message names the holder's PID).
    try:
        store = Store(data_dir)
    except BaseException:
        if tmp is not None:
            tmp.cleanup()
        raise
    try:
        # a scan is announced as the bench opens (open_instrument's ``expect``): what it needs starts
        # now, beside this set-up; a command without one (a self-test, a calibration, a stream) leaves
        # the kernels to the synthesis's break-even, as a one-shot process that may never pass it
        inst = base.open_instrument(cfg, bench="embedded", expect=scan, preload=False, **kw)
    except BaseException:
        store.close()
        if tmp is not None:
            tmp.cleanup()
        raise
    use_cache = tmp is not None and not getattr(args, "no_cal_cache", False)
    try:
        seeded = _seed_from_cache(cfg, store) if use_cache else None
        setup = instrument_setup(cfg, inst)
        if use_cache and factory:
            _seed_records(setup, store)
        worker = ScanWorker(inst, store, laser=cfg.laser, meta=meta, max_queue=1, optics=cfg.resolved.optics,
                            recalibrate_delta_c=cfg.scan.recalibrate_delta_c, setup=setup,
                            warm_dsp_pool=scan is None)
        if factory and cfg.sim.factory_calibration and inst.simulated:
            worker.factory = _factory(cfg, scene_path, "the user's cache" if use_cache else
                                      "the data directory" if args.data_dir else "this run only (--no-cal-cache)")
            worker.warm_dsp_pool = True     # its scans come first, whatever the scan itself needs
        worker.start()
        try:
            yield worker, store, inst
        finally:
            worker.stop()
            if use_cache:
                _update_cache(cfg, store, seeded)
                if worker.factory is not None and worker.factory.result is not None:
                    _keep_records(setup, worker.factory.result)
    finally:
        try:
            store.close()
            inst.close()
        finally:
            if tmp is not None:
                tmp.cleanup()


def _seed_from_cache(cfg, store) -> str | None:
    """Put the cached calibration of this configuration into the (temporary) store; its id or None.
    The worker then reuses it unless the laser temperature moved (scan.recalibrate_delta_c)."""
    from ..store import calcache
    cal = calcache.load(cfg)
    if cal is None or cal.laser != cfg.laser:
        return None
    return store.save_calibration(cal, cal_id=cal.meta.get("id"))


def _update_cache(cfg, store, seeded: str | None) -> None:
    """Keep a calibration made by this run (none, or the seeded one: nothing to write)."""
    from ..store import calcache
    cal = store.latest_calibration(cfg.laser)
    if cal is not None and cal.meta.get("id") != seeded:
        calcache.save(cfg, cal)


def _factory(cfg, scene_path: str | None, where: str):
    """The factory calibration of ``cfg``'s bench, which puts the scan's scene back when it is done."""
    import sys
    import tomllib
    from ..jobs.guided import FactoryCalibration
    scene_file = scene_path or str(cfg.resolve_path(cfg.sim.scene))

    def scene() -> dict:
        with open(scene_file, "rb") as f:
            return tomllib.load(f)

    return FactoryCalibration(nominal_delay_s=cfg.monitor.delay_s, scene=scene,
                              announce=lambda msg: print(f"lidarctl: {msg}; kept in {where} for the next runs "
                                                         "(--uncalibrated skips it)", file=sys.stderr))


def _seed_records(setup, store) -> int:
    """Put the cached range/pointing records of this set-up into the (temporary) store."""
    from ..store import calcache
    recs = calcache.load_records(setup.hash) or []
    for rec in recs:
        store.geometry.import_record(rec)
    return len(recs)


def _keep_records(setup, result: dict) -> None:
    from ..store import calcache
    calcache.save_records(setup.hash, [result["range"], result["pointing"]])


def resolve(path: str | None) -> str | None:
    return None if path is None else str(Path(path).resolve())
