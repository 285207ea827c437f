"""What every command of ``lidarctl`` and ``lidard`` shares: the one-line error contract, the argparse
subclass that keeps it, configuration loading, the lazy hook into the composition root, atomic file
output and the runner that turns exceptions into exit codes.

Every failure (bad option, unreachable daemon, bad configuration, device fault) is printed as ONE
line on stderr with a non-zero exit status; ``LIDARD_DEBUG=1`` re-raises for the traceback.
Ctrl-C exits 130 (128 + SIGINT, the shell convention). SIGTERM (what ``timeout``, systemd and CI
runners send) and SIGHUP (a closed terminal) stop a command the same way (:func:`stop_signals`): the
command cleans up as after Ctrl-C (a scan keeps its points, a temporary store is removed) and exits
128 + the signal's number, 143 and 129.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import signal
import sys
from pathlib import Path
from typing import Any, NoReturn
from collections.abc import Callable

from ..errors import ConfigError, LidardError

DEFAULT_URL = "http://127.0.0.1:8470"
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_STUCK = 3          # the self-test ran and found a stuck switch
EXIT_INTERRUPTED = 130  # 128 + SIGINT


class CliError(LidardError):
    """A user-facing failure; printed as one line."""


class Interrupted(Exception):
    """A stop signal arrived and the command finished cleanly (partial results kept); exit 128 + its
    number (130 for Ctrl-C)."""

    def __init__(self, message: str = "", signum: int = signal.SIGINT):
        super().__init__(message)
        self.signum = int(signum)


class StopSignal(KeyboardInterrupt):
    """SIGTERM or SIGHUP, raised in the main thread where Ctrl-C raises KeyboardInterrupt, so every
    ``except KeyboardInterrupt`` cleanup path serves them too."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)


STOP_SIGNALS = (signal.SIGTERM, signal.SIGHUP)


def signal_of(exc: BaseException) -> int:
    """The signal number behind an interruption (SIGINT for a plain KeyboardInterrupt)."""
    return int(getattr(exc, "signum", signal.SIGINT))


def describe_signal(signum: int) -> str:
    """``SIGINT (Ctrl-C)``, ``SIGTERM``, ``SIGHUP``: the words of a stop reason."""
    name = signal.Signals(signum).name
    return f"{name} (Ctrl-C)" if signum == signal.SIGINT else name


@contextlib.contextmanager
def stop_signals():
    """While the block runs, SIGTERM and SIGHUP raise :class:`StopSignal` in the main thread. A signal
    ignored on entry (SIGHUP under ``nohup``) stays ignored; the previous handlers come back after."""
    import threading
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def raise_stop(signum, frame):
        raise StopSignal(signum)

    previous = {}
    for sig in STOP_SIGNALS:
        if signal.getsignal(sig) is not signal.SIG_IGN:
            previous[sig] = signal.signal(sig, raise_stop)
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) so scripts can parse stderr."""

    def error(self, message: str) -> NoReturn:
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(EXIT_USAGE)


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keep the examples' line breaks; each flag's help says its unit and default itself."""


def open_instrument(cfg, **kw):
    """The composition root (lidard.instrument), imported only when a command needs hardware/sim.

    Commands call it as ``base.open_instrument`` so that tests can replace it in one place.
    """
    try:
        from ..instrument import open_instrument as _open
    except ImportError as exc:
        raise CliError(f"the instrument layer is not available ({exc})") from None
    return _open(cfg, **kw)


def load_config(path: str | None, profile: str | None = None):
    """The configuration file (default search path when ``path`` is None), with ``profile`` swapped in."""
    from ..config import Config
    from ..config import load_config as _load
    cfg = _load(path)
    if profile is not None and profile != cfg.profile:
        data = cfg.model_dump()
        data.update(profile=profile, lens=None, source=cfg.source, base_dir=cfg.base_dir)
        cfg = Config.model_validate(data)
        _ = cfg.resolved      # the swapped-in profile resolved (and checked) now
    return cfg


def check_out(path: str | Path | None, flag: str = "--out") -> None:
    """Refuse an output path whose directory does not exist, before any work: a typo in a directory
    is named instead of silently created (the file itself is written atomically later)."""
    if path is None:
        return
    parent = Path(path).expanduser().absolute().parent
    if not parent.is_dir():
        what = "is not a directory" if parent.exists() else "does not exist"
        raise CliError(f"{flag} {path}: directory {parent} {what}; create it first")


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    from ..outputs import atomic_write
    with atomic_write(path) as f:
        f.write(data)


def copy_atomic(src: Path, dst: str | Path) -> None:
    from ..outputs import atomic_write
    with open(src, "rb") as fin, atomic_write(dst) as fout:
        shutil.copyfileobj(fin, fout)


def run(fn: Callable[[Any], int], args, prog: str) -> int:
    """Call a command; map its exceptions to one stderr line and an exit status."""
    try:
        return fn(args)
    except (KeyboardInterrupt, Interrupted) as exc:
        signum = signal_of(exc)
        detail = str(exc) if isinstance(exc, Interrupted) and str(exc) else ""
        by = "" if signum == signal.SIGINT else f" by {describe_signal(signum)}"
        sys.stderr.write(f"{prog}: interrupted{by}{': ' + detail if detail else ''}\n")
        return 128 + signum
    except Exception as exc:
        if os.environ.get("LIDARD_DEBUG"):
            raise
        msg = str(exc).replace("\n", " ").strip()
        if isinstance(exc, (CliError, ConfigError)):
            sys.stderr.write(f"{prog}: error: {msg}\n")
        else:
            sys.stderr.write(f"{prog}: error: {type(exc).__name__}: {msg}\n")
        return EXIT_ERROR
