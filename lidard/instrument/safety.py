"""The safety monitor: interlock/fault check and the safe-state path (docs/reliability.md).

The laser and the FPSA's high-voltage switch drive (dissertation §4.3.3: the HV583 converters behind
the FPGA that drive the MEMS actuators) are the two outputs that must go down when
the interlock opens or the controller latches a fault. :meth:`SafetyMonitor.check` is one Modbus
request (the controller's flags); :meth:`SafetyMonitor.trip` commands laser off and HV off FIRST,
then reads both back. The controller's own hardware interlock drops the outputs at once anyway; this
is the host's view of it, so the points measured while the light was unknown are discarded.

Two independent checks run while the outputs may be on (from :meth:`~SafetyMonitor.bring_up` to
:meth:`~SafetyMonitor.bring_down` or a trip):

* the **watch** (:class:`SafetyWatch`): a daemon thread that reads the flags every ``period_s`` of
  WALL time (``[daemon] safety_period_s``, 20 ms) and trips on its own, whatever the scan thread is
  doing (a DSP flush of an 8 MiB batch takes most of a second of host time, during which the
  virtual clock does not move);
* the scan loop's check between digitizer reads (at most ``SAFETY_CHECK_S`` of hardware time apart,
  the virtual-clock period on the bench); it also decides which points are kept, since it runs right
  after each read. After the watch tripped, :meth:`~SafetyMonitor.check` answers the watch's reason,
  so every caller (scan, linearization, self-test) stops at its next check.

Locks, and why the watch cannot deadlock: the controller driver serializes its Modbus requests with
one lock held for a single request/response (never across a sequence such as ``bring_up``'s
readback waits), so the watch's flags read waits for at most one request in flight (bounded by the
driver's ``timeout_s``) and then interleaves with the scan thread's sequence. The monitor's own
``_trip_lock`` is taken before the driver's lock and never the other way round; the watch takes no
instrument lock. While a trip is recorded, the readback waits of ``bring_up`` stop (their sleep
raises :class:`SafetyStopped`) instead of waiting out their timeout for outputs the watch turned off.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Any
from collections.abc import Callable

from drivers.controller.driver import SettleCheck

from .selftest_analysis import hv_margin_problem
from .errors import FaultsStillOpen, InstrumentError

log = logging.getLogger(__name__)

LASER_OFF_MA = 0.5       # readback tolerances of "off" (the driver's SettleCheck defaults)
HV_OFF_V = 0.25
SWITCH_INTERVAL_S = 0.001  # interpreter thread switch interval while the watch runs (see start_watch)


class SafetyStopped(InstrumentError):
    """The safety monitor tripped while the outputs were being brought up (laser and HV already off)."""


def latched_state(controller: Any) -> dict[str, Any]:
    """``{"latched": [fault names], "interlock_closed": bool}``: two Modbus reads."""
    return {"latched": sorted(f.name for f in controller.faults()),
            "interlock_closed": bool(controller.interlock_closed())}


def acknowledge(controller: Any) -> list[str]:
    """Clear the controller's latched faults, only once their causes are gone (a manual reset, as
    laser safety expects). Answers the names cleared; raises :class:`FaultsStillOpen` naming what is
    still open (the interlock loop reads open: nothing is sent; a fault the device keeps latched
    through CLEAR_FAULTS because its cause persists, e.g. an HV supply trip)."""
    state = latched_state(controller)
    if not state["interlock_closed"]:
        raise FaultsStillOpen(["INTERLOCK_OPEN (the interlock loop reads open: close it first)"])
    if not state["latched"]:
        return []
    remaining = sorted(f.name for f in controller.clear_faults())
    if remaining:
        raise FaultsStillOpen([f"{name} (its cause is still present)" for name in remaining])
    return state["latched"]


class SafetyMonitor:
    """Interlock/fault check, safe state, the wall-clock watch, and bringing the laser and HV up and down."""

    def __init__(self, controller: Any, *, laser_current_ma: float, hv_v: float,
                 sleep: Callable[[float], object], now: Callable[[], float], period_s: float | None = 0.02,
                 pull_in_v: float | None = None, spread_v: float = 0.0):
        self.controller = controller
        self.laser_current_ma = laser_current_ma     # setpoints of bring_up()
        self.hv_v = hv_v
        self.period_s = period_s                     # wall-clock watch period; None: no watch thread
        self.pull_in_v = pull_in_v                   # the switches' pull-in (profile), checked at bring-up
        self.spread_v = spread_v
        self._sleep = sleep
        self._now = now
        self._trip_lock = threading.Lock()
        self._tripped: dict[str, Any] | None = None  # the trip of the current bring_up session
        self._watch: SafetyWatch | None = None
        self._switch_s: float | None = None           # the interpreter's switch interval before the watch
        self.last_trip: dict[str, Any] | None = None  # the latest trip, with wall (monotonic) stamps
        self.trip_event = threading.Event()           # set by a trip, cleared by the next bring_up

    def settle(self, *, stop_on_trip: bool = False) -> SettleCheck:
        """The controller's readback wait, on the instrument's clock (virtual on a bench); for a
        bring-up it gives up as soon as a trip is recorded."""
        return SettleCheck(sleep=self._settle_sleep if stop_on_trip else self._sleep, timeout_s=30.0, poll_s=0.002)

    def _settle_sleep(self, dt_s: float) -> None:
        # a bring_up waiting for readbacks gives up at once when the watch turned the outputs off
        if self._tripped is not None:
            raise SafetyStopped(f"bring-up stopped by the safety monitor: {self._tripped['reason']}")
        self._sleep(dt_s)

    # -- the check and the trip -------------------------------------------------------------------
    def check(self) -> str | None:
        """None when the interlock is closed and no fault is latched; else the reason. After the watch
        tripped, its reason (the outputs are already down)."""
        tripped = self._tripped
        if tripped is not None:
            return tripped["reason"]
        return self.read_flags()

    def read_flags(self) -> str | None:
        """One Modbus request: None when the interlock is closed and no fault is latched."""
        try:
            flags = self.controller.flags()
        except Exception as exc:
            # cannot see the interlock: treat as unsafe (fail safe)
            return f"controller: interlock state unreadable ({type(exc).__name__}: {exc})"
        if not flags.interlock_closed:
            return "controller: interlock opened mid-scan"
        if flags.fault_active:
            try:
                names = sorted(f.name for f in self.controller.faults())
            except Exception:
                names = ["unknown"]
            return f"controller: fault latched mid-scan ({', '.join(names)})"
        return None

    @property
    def tripped(self) -> dict[str, Any] | None:
        """``{"reason", "safe", "by"}`` once this session tripped (watch or check), else None."""
        return self._tripped

    def trip(self, reason: str | None = None, *, by: str = "check") -> dict[str, Any]:
        """Laser off and HV off commanded FIRST, then both read back; returns the readbacks. A second
        trip of the same session (the watch and the scan thread both saw it) answers the first's."""
        t_detect = time.monotonic()
        with self._trip_lock:
            if self._tripped is not None:
                return self._tripped["safe"]
            safe = self._outputs_off()
            safe["detected_by"] = by
            self._tripped = {"reason": reason or "controller: safety trip", "safe": safe, "by": by}
            self.last_trip = {**self._tripped, "wall_detected_s": t_detect,
                              "wall_off_commanded_s": safe.pop("_wall_cmd"), "wall_safe_s": time.monotonic()}
            self.trip_event.set()
        log.warning("safety trip (%s): %s; %s", by, self._tripped["reason"], describe_safe(safe))
        return safe

    def _outputs_off(self) -> dict[str, Any]:
        """Laser and HV off, read back (two requests per poll: status + flags), then setpoints to 0.

        Its own short sequence rather than the driver's ``bring_down`` (which repeats the enables and
        waits for each output in turn): every Modbus round trip here is on the path to the safe
        state, and with the DSP busy each one can wait for the interpreter."""
        c, errors = self.controller, []
        for what, fn in (("laser off", lambda: c.laser_enable(False)), ("HV off", lambda: c.hv_enable(False))):
            try:
                fn()
            except Exception as exc:
                errors.append(f"{what}: {type(exc).__name__}: {exc}")
        wall_cmd = time.monotonic()
        t_cmd = float(self._now())      # read after the commands: nothing may delay them
        out: dict[str, Any] = {"off_commanded_at_s": t_cmd, "_wall_cmd": wall_cmd}
        try:
            out.update(self._read_back_off())
        except Exception as exc:
            errors.append(f"readback: {type(exc).__name__}: {exc}")
        out["safe_at_s"] = float(self._now())
        # the setpoints to 0 as well (so nothing comes back at the old setpoints on a later enable);
        # after the readback: the disabled outputs are what makes the state safe
        for what, fn in (("laser current to 0", lambda: c.set_laser_current_ma(0.0)),
                         ("HV to 0", lambda: c.set_hv_v(0.0))):
            try:
                fn()
            except Exception as exc:
                errors.append(f"{what}: {type(exc).__name__}: {exc}")
        out["errors"] = errors
        out["safe"] = (not errors and not out.get("laser_on") and not out.get("hv_on")
                       and out.get("laser_ma", 1.0) <= LASER_OFF_MA and out.get("hv_v", 1.0) <= HV_OFF_V)
        return out

    def _read_back_off(self) -> dict[str, Any]:
        """Poll until both outputs read off (or the readback timeout passes on the instrument's clock)."""
        sc, waited_s = self.settle(), 0.0
        while True:
            st, fl = self.controller.status(), self.controller.flags()
            got = {"laser_ma": float(st.laser_current_ma), "hv_v": float(st.hv_v),
                   "laser_on": bool(fl.laser_on), "hv_on": bool(fl.hv_on)}
            off = (got["laser_ma"] <= LASER_OFF_MA and got["hv_v"] <= HV_OFF_V
                   and not got["laser_on"] and not got["hv_on"])
            if off or waited_s >= sc.timeout_s:
                return got
            sc.sleep(sc.poll_s)
            waited_s += sc.poll_s

    # -- the wall-clock watch -----------------------------------------------------------------------
    def start_watch(self) -> None:
        """A new session: forget the last trip and start the watch thread (once)."""
        with self._trip_lock:
            self._tripped = None
            self.trip_event.clear()
        if self.period_s is not None and self._watch is None:
            self._watch = SafetyWatch(self, self.period_s)
            self._watch.start()
            # While the DSP thread computes it holds the interpreter lock for up to the switch
            # interval (5 ms by default) before a waiting thread gets it, and the watch's trip path
            # needs the lock ~10 times (each Modbus reply). 1 ms keeps that wait small; the DSP's
            # numpy work barely notices. Restored when the watch stops.
            self._switch_s = sys.getswitchinterval()
            sys.setswitchinterval(min(self._switch_s, SWITCH_INTERVAL_S))

    def stop_watch(self) -> None:
        """Stop the watch thread and wait for it (it is never mid-trip when this returns)."""
        watch, self._watch = self._watch, None
        if watch is not None:
            watch.stop()
            if self._switch_s is not None:
                sys.setswitchinterval(self._switch_s)
                self._switch_s = None

    @property
    def watching(self) -> bool:
        return self._watch is not None and self._watch.alive

    # -- outputs up and down ------------------------------------------------------------------------
    def bring_up(self, *, check_hv: bool = True) -> None:
        """Refuse with the interlock open; else start the watch, then laser and HV up to their setpoints
        and read back. The watch runs until :meth:`bring_down` (or the end of a scan after a trip).
        ``check_hv``: refuse (outputs down again) when the HV read back cannot pull in every switch
        (selftest_analysis.hv_margin_problem); the self-test skips it to diagnose instead."""
        if not self.controller.interlock_closed():
            raise InstrumentError("controller: interlock open; close it before scanning")
        self.start_watch()
        try:
            self.controller.bring_up(self.laser_current_ma, self.hv_v, settle_check=self.settle(stop_on_trip=True))
        except BaseException:
            self._end_failed_bring_up()
            raise
        if self._tripped is not None:
            # the watch tripped between two steps of the sequence: whatever came on after it, off again
            self._end_failed_bring_up()
            raise SafetyStopped(f"bring-up stopped by the safety monitor: {self._tripped['reason']}")
        if check_hv and self.pull_in_v is not None:
            problem = hv_margin_problem(float(self.controller.hv_v()), self.pull_in_v, self.spread_v)
            if problem is not None:
                self.bring_down()
                raise InstrumentError(f"controller: {problem}")

    def _end_failed_bring_up(self) -> None:
        self.stop_watch()
        if self._tripped is not None:
            for fn in (lambda: self.controller.laser_enable(False), lambda: self.controller.hv_enable(False)):
                try:
                    fn()
                except Exception as exc:
                    log.warning("output off after a tripped bring-up failed: %s", exc)

    def bring_down(self) -> None:
        try:
            self.controller.bring_down(settle_check=self.settle())
        except Exception:
            # Safety first: at least command the outputs off even when the readback fails.
            for fn in (lambda: self.controller.laser_enable(False), lambda: self.controller.hv_enable(False)):
                try:
                    fn()
                except Exception:
                    pass
            raise
        finally:
            self.stop_watch()


class SafetyWatch:
    """The wall-clock watch: a daemon thread reading the flags every ``period_s`` and tripping once.

    Its period is wall time on purpose (``threading.Event.wait``): it is the host's real-time check,
    independent of the acquisition's virtual clock and of the DSP. It ends after a trip (the outputs
    are down and the session is over) or when stopped; being a daemon thread it cannot keep the
    process alive, and :meth:`SafetyMonitor.bring_down` / ``stop_watch`` join it.
    """

    def __init__(self, monitor: SafetyMonitor, period_s: float):
        if not (isinstance(period_s, (int, float)) and 0 < period_s <= 1.0):
            raise InstrumentError(f"daemon.safety_period_s must be in (0, 1] s, got {period_s!r}")
        self.monitor = monitor
        self.period_s = float(period_s)
        self.checks = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lidard-safety-watch", daemon=True)

    def start(self) -> None:
        self._thread.start()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=10.0)

    def _run(self) -> None:
        next_t = time.monotonic() + self.period_s
        # fixed-rate schedule: a slow check does not push every later one back
        while not self._stop.wait(max(0.0, next_t - time.monotonic())):
            next_t += self.period_s
            if self.monitor.tripped is not None:
                return          # the scan thread's own check tripped first
            reason = self.monitor.read_flags()
            self.checks += 1
            if reason is not None and not self._stop.is_set():
                self.monitor.trip(reason, by="watch")
                return


def describe_safe(safe: dict[str, Any]) -> str:
    """One line for the readbacks ``trip()`` returned (stop_reason and error messages)."""
    if safe.get("safe"):
        return (f"laser and HV brought down and read back (laser {safe['laser_ma']:.2f} mA, "
                f"HV {safe['hv_v']:.2f} V)")
    return "SAFE STATE NOT CONFIRMED: " + "; ".join(safe.get("errors") or ["readback out of tolerance"])
