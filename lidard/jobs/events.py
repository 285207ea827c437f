"""Where a scan's progress goes besides the store: per-scan subscribers and live listeners (lidard.jobs).

Subscribers (the SSE endpoint, the CLI's progress bar) follow one scan by id; event listeners (the
Foxglove server, the viewer) see every scan's events; point listeners get the points of a scan as they
are measured and once more, whole, when it is written. A broken subscriber or listener is logged and
skipped: it never stops the scan that feeds it.
"""

from __future__ import annotations

import collections
import logging
import threading
from typing import Any
from collections.abc import Callable

log = logging.getLogger("lidard.jobs")

Event = dict[str, Any]
Subscriber = Callable[[Event], None]
# (scan_id, POINT_DTYPE records, final): a batch measured so far, or (final=True) the whole cloud
PointListener = Callable[[str, Any, bool], None]


class EventHub:
    """The subscribers and listeners of one worker; safe to call from any thread."""

    def __init__(self) -> None:
        self._subs: dict[str, list[Subscriber]] = collections.defaultdict(list)
        self._subs_lock = threading.Lock()
        self._point_listeners: list[PointListener] = []
        self._event_listeners: list[Subscriber] = []

    def subscribe(self, scan_id: str, fn: Subscriber) -> Callable[[], None]:
        with self._subs_lock:
            self._subs[scan_id].append(fn)

        def unsubscribe() -> None:
            with self._subs_lock:
                lst = self._subs.get(scan_id, [])
                if fn in lst:
                    lst.remove(fn)
                if not lst:
                    self._subs.pop(scan_id, None)
        return unsubscribe

    def add_point_listener(self, fn: PointListener) -> None:
        self._point_listeners.append(fn)

    def add_event_listener(self, fn: Subscriber) -> None:
        self._event_listeners.append(fn)

    def points_out(self, scan_id: str, points, final: bool) -> None:
        for fn in list(self._point_listeners):
            try:
                fn(scan_id, points, final)
            except Exception:  # a broken viewer must not stop the scan
                log.exception("point listener for scan %s failed", scan_id)

    def publish(self, scan_id: str, event: Event) -> None:
        with self._subs_lock:
            subs = list(self._subs.get(scan_id, ())) + self._event_listeners
        for fn in subs:
            try:
                fn(event)
            except Exception:  # a broken subscriber must not stop the scan
                log.exception("progress subscriber for scan %s failed", scan_id)
