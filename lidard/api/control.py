"""Access control of the daemon: bearer token for mutating requests, the control lock, body limits.

A lab daemon next to a laser and a 50 V MEMS supply (§4.3) must let observers watch while exactly
one client steers the instrument. Three independent gates, applied in this order to every request:

1. ``BodySizeLimit`` (pure ASGI middleware): a body larger than ``max_body_bytes`` is answered 413,
   whether the client declared it in ``Content-Length`` or streamed it chunk by chunk. Nothing is
   handed to the route, so no half-read body can reach the instrument.
2. Same origin, then the bearer token, for POST/PUT/PATCH/DELETE only: a browser request from
   another origin is 403 (``cross_origin_refusal``: no web page may steer a loopback daemon);
   with a token, ``Authorization: Bearer <token>`` is needed (401 otherwise, compared in constant
   time). GET/HEAD/OPTIONS stay open so observers can watch without the secret.
3. The control lock (``ControlLock``): ``POST /control`` takes a lease for one named client. While
   a lease is held, a mutating request without the matching ``X-Lidard-Lease`` header is 423
   (Locked) naming the holder. With no lease held mutating requests pass (single-user lab default).
   A lease expires ``ttl_s`` after its last use; every request that carries it renews it. The lock
   reads time from an injected clock (``time.monotonic`` by default) so tests advance it by hand.
   Every 423 says what to send (the holder's lease as ``X-Lidard-Lease``) and that the holder may
   release it or hand it over. ``POST /control/handover`` (with the current lease) gives the lock to a
   named client under a fresh lease and voids the old one: the owner moves control between its own
   clients (the web viewer re-taking its lease after a reload, whose old page may still be sending
   its release) without a window in which another client could take it.
   Lease tokens are hex (``new_lease_token``): never a leading "-" (``token_urlsafe`` gives one in
   1/32 of leases, and ``lidarctl ... --lease <token>`` then reads it as an option), nothing a
   shell or an HTTP header would mangle.

The lock guards the HTTP side only; the one scan worker that owns the hardware is unchanged.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

from fastapi import APIRouter, HTTPException, Request
from fastapi.responses import JSONResponse

from ..errors import LidardError
from .problems import PROBLEM_MEDIA_TYPE, document, problem, problem_bytes
from .schemas import ControlAcquire, ControlLease, ControlStatus

LEASE_HEADER = "X-Lidard-Lease"
MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
DEFAULT_LEASE_TTL_S = 300.0
DEFAULT_MAX_BODY_BYTES = 1 << 20


@dataclass(frozen=True)
class Lease:
    """One controlling client. ``expires_at`` is on the lock's clock (monotonic seconds)."""

    token: str
    holder: str
    acquired_at: float
    expires_at: float


def new_lease_token() -> str:
    """A fresh lease: 192 random bits as 48 lower-case hex digits (never starts with "-")."""
    return secrets.token_hex(24)


class LockHeld(Exception):
    """Another client holds the control lease (HTTP 423)."""

    def __init__(self, holder: str, expires_in_s: float, action: str):
        self.holder = holder
        self.expires_in_s = expires_in_s
        super().__init__(f"control lock held by {holder!r} (expires in {expires_in_s:.0f} s unless renewed); "
                         f"{action}; the holder can release it (DELETE /control) or hand it over "
                         "(POST /control/handover)")


class NotHeld(LidardError):
    """A handover while nobody holds the lock: take it with POST /control instead."""

    http_status = 409


class ControlLock:
    """At most one lease at a time; thread-safe (routes run on the threadpool and the event loop)."""

    def __init__(self, ttl_s: float = DEFAULT_LEASE_TTL_S, clock: Callable[[], float] = time.monotonic):
        if not (ttl_s > 0):
            raise ValueError(f"control lease ttl_s must be > 0, got {ttl_s!r}")
        self.ttl_s = float(ttl_s)
        self._clock = clock
        self._lease: Lease | None = None
        self._mutex = threading.Lock()

    def _current(self, now: float) -> Lease | None:
        if self._lease is not None and now >= self._lease.expires_at:
            self._lease = None  # expired: as if released
        return self._lease

    def _matches(self, lease: Lease, presented: str | None) -> bool:
        return presented is not None and hmac.compare_digest(presented.encode(), lease.token.encode())

    def holder(self) -> Lease | None:
        with self._mutex:
            return self._current(self._clock())

    def acquire(self, client: str, presented: str | None = None) -> Lease:
        """A new lease for ``client``; renews instead when ``presented`` is the current lease."""
        with self._mutex:
            now = self._clock()
            cur = self._current(now)
            if cur is not None:
                if not self._matches(cur, presented):
                    raise LockHeld(cur.holder, cur.expires_at - now,
                                   f"send its lease as {LEASE_HEADER} to renew it, or wait for it to expire")
                self._lease = Lease(cur.token, client, cur.acquired_at, now + self.ttl_s)
            else:
                self._lease = Lease(new_lease_token(), client, now, now + self.ttl_s)
            return self._lease

    def handover(self, client: str, presented: str | None) -> Lease:
        """Give the lock to ``client`` under a fresh lease; ``presented`` must be the current one,
        which is void from now on."""
        with self._mutex:
            now = self._clock()
            cur = self._current(now)
            if cur is None:
                raise NotHeld("no control lease is held, so there is none to hand over; take it with POST /control")
            if not self._matches(cur, presented):
                raise LockHeld(cur.holder, cur.expires_at - now, f"a handover needs its {LEASE_HEADER} header")
            self._lease = Lease(new_lease_token(), client, now, now + self.ttl_s)
            return self._lease

    def release(self, presented: str | None) -> Lease | None:
        """Release the lease ``presented``; returns the lease released, None if none was held."""
        with self._mutex:
            now = self._clock()
            cur = self._current(now)
            if cur is None:
                return None
            if not self._matches(cur, presented):
                raise LockHeld(cur.holder, cur.expires_at - now, f"send its {LEASE_HEADER} to release it")
            self._lease = None
            return cur

    def check(self, presented: str | None) -> None:
        """Let a mutating request pass (renewing the lease it carries) or raise LockHeld."""
        with self._mutex:
            now = self._clock()
            cur = self._current(now)
            if cur is None:
                return
            if not self._matches(cur, presented):
                raise LockHeld(cur.holder, cur.expires_at - now,
                               f"mutating requests need its lease in the {LEASE_HEADER} header")
            self._lease = Lease(cur.token, cur.holder, cur.acquired_at, now + self.ttl_s)

    def renew(self, presented: str | None) -> None:
        """Any request (read or write) carrying the current lease keeps it alive."""
        with self._mutex:
            cur = self._current(self._clock())
            if cur is not None and self._matches(cur, presented):
                self._lease = Lease(cur.token, cur.holder, cur.acquired_at, self._clock() + self.ttl_s)

    def seconds_left(self, lease: Lease) -> float:
        return max(0.0, lease.expires_at - self._clock())


def token_ok(token: str, authorization: str | None) -> bool:
    """Constant-time comparison of an ``Authorization`` header with ``Bearer <token>``."""
    return hmac.compare_digest((authorization or "").encode(), f"Bearer {token}".encode())


class BodySizeLimit:
    """Pure ASGI middleware: 413 for a request body over ``max_body_bytes``.

    A declared ``Content-Length`` over the limit is refused before the body is read. A streamed
    body (chunked, or a lying ``Content-Length``) is counted as it is received; the route's read
    fails once the count passes the limit and, if no response has started, the client gets 413.
    """

    def __init__(self, app, max_body_bytes: int = DEFAULT_MAX_BODY_BYTES):
        if not (isinstance(max_body_bytes, int) and max_body_bytes > 0):
            raise ValueError(f"max_body_bytes must be an int > 0, got {max_body_bytes!r}")
        self.app = app
        self.max_body_bytes = max_body_bytes

    async def _reject(self, send) -> None:
        body = problem_bytes(413, f"request body larger than {self.max_body_bytes} bytes")
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                                (b"content-length", str(len(body)).encode()),
                                (b"connection", b"close")]})
        await send({"type": "http.response.body", "body": body})

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", ()):
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = -1
                if declared < 0:
                    await _bad_request(send, b"invalid Content-Length header")
                    return
                if declared > self.max_body_bytes:
                    await self._reject(send)
                    return
        received = 0
        started = False
        too_big = False

        async def limited_receive() -> dict[str, Any]:
            nonlocal received, too_big
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_body_bytes:
                    too_big = True
                    # An HTTPException passes through FastAPI's body parsing untouched (anything
                    # else would become a 400) and is rendered by Starlette's exception layer.
                    raise HTTPException(413, f"request body larger than {self.max_body_bytes} bytes")
            return message

        async def tracking_send(message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except Exception:
            # Frameworks may wrap the exception raised inside receive(); the flag says what it was.
            if not too_big:
                raise
            if not started:
                await self._reject(send)


async def _bad_request(send, detail: bytes) -> None:
    body = problem_bytes(400, detail.decode())
    await send({"type": "http.response.start", "status": 400,
                "headers": [(b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                            (b"content-length", str(len(body)).encode())]})
    await send({"type": "http.response.body", "body": body})


# ---------------------------------------------------------------------------------- the /control API
def _lock(request: Request) -> ControlLock:
    return request.app.state.control_lock


def _wall(lock: ControlLock, lease: Lease) -> float:
    # The lock runs on a monotonic clock; clients get Unix time, which they can compare with theirs.
    return time.time() + lock.seconds_left(lease)


router = APIRouter(prefix="/control", tags=["control"])


@router.get("", response_model=ControlStatus)
def control_status(request: Request) -> ControlStatus:
    lock = _lock(request)
    cur = lock.holder()
    if cur is None:
        return ControlStatus(held=False, ttl_s=lock.ttl_s)
    return ControlStatus(held=True, holder=cur.holder, expires_at=_wall(lock, cur),
                         expires_in_s=lock.seconds_left(cur), ttl_s=lock.ttl_s)


@router.post("", response_model=ControlLease, status_code=201,
             responses={423: {"description": "another client holds the lock"}})
def control_acquire(body: ControlAcquire, request: Request) -> ControlLease:
    """Take the control lock (or renew it, when the request carries the current lease)."""
    lock = _lock(request)
    lease = lock.acquire(body.client, request.headers.get(LEASE_HEADER))
    return ControlLease(lease=lease.token, holder=lease.holder, expires_at=_wall(lock, lease), ttl_s=lock.ttl_s)


@router.delete("", response_model=ControlStatus,
               responses={423: {"description": "the request does not carry the current lease"}})
def control_release(request: Request) -> ControlStatus:
    """Release the lock; needs the lease. Releasing when nobody holds it is a no-op."""
    lock = _lock(request)
    lock.release(request.headers.get(LEASE_HEADER))
    return ControlStatus(held=False, ttl_s=lock.ttl_s)


@router.post("/handover", response_model=ControlLease, status_code=201,
             responses={423: {"description": "the request does not carry the current lease"},
                        409: {"description": "nobody holds the lock (take it with POST /control)"}})
def control_handover(body: ControlAcquire, request: Request) -> ControlLease:
    """Hand the lock to ``client`` under a fresh lease (answered here); the lease sent is void after."""
    lock = _lock(request)
    lease = lock.handover(body.client, request.headers.get(LEASE_HEADER))   # NotHeld: 409
    return ControlLease(lease=lease.token, holder=lease.holder, expires_at=_wall(lock, lease), ttl_s=lock.ttl_s)


def _host_is_loopback(host_header: str) -> bool:
    host = host_header.rsplit("]", 1)[0].lstrip("[") if host_header.startswith("[") else host_header.split(":")[0]
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def cross_origin_refusal(origin: str | None, host: str | None, token_set: bool) -> str | None:
    """Why a mutating request from a web page must be refused, or None.

    Browsers send ``Origin`` on cross-origin POSTs, and a "simple" POST (no body, or text/plain)
    needs no CORS preflight, so without this any page the lab user opens could start a scan or a
    linearization (laser and HV on) on a loopback daemon that has no token. Command-line clients
    send no ``Origin``. Same-origin pages (the daemon's own /docs) pass. Without a token the Host
    must also be a loopback name or address, so a DNS-rebinding page (its own name resolving to
    127.0.0.1, hence "same origin") is refused as well.
    """
    if origin is None:
        return None
    origin_host = urlsplit(origin).netloc if "://" in origin else ""
    if not origin_host or origin_host.lower() != (host or "").lower():
        return f"cross-origin request from {origin!r} refused (Host {host!r})"
    if not token_set and not _host_is_loopback(origin_host):
        return f"browser request for {origin_host!r} refused: without an API token only loopback pages may steer"
    return None


def guard(token: str | None) -> Callable[[Request], None]:
    """App-wide dependency: same-origin check and token for mutating requests, then the control lock."""

    def check(request: Request) -> None:
        presented = request.headers.get(LEASE_HEADER)
        if request.method not in MUTATING_METHODS:
            _lock(request).renew(presented)
            return
        why = cross_origin_refusal(request.headers.get("origin"), request.headers.get("host"), token is not None)
        if why is not None:
            raise HTTPException(403, why)
        if token is not None and not token_ok(token, request.headers.get("authorization")):
            raise HTTPException(401, "mutating requests need 'Authorization: Bearer <token>' "
                                     "(missing or wrong token)", headers={"WWW-Authenticate": "Bearer"})
        route = request.scope.get("route")
        if getattr(route, "path", None) in (router.prefix, router.prefix + "/handover"):
            return  # /control itself decides (acquire, renew, release, hand over)
        _lock(request).check(presented)

    return check


def locked_response(exc: LockHeld) -> JSONResponse:
    return problem(423, str(exc), holder=exc.holder)


_GATE_RESPONSES = {
    "403": "a browser request from another origin (Origin header not matching Host)",
    "400": "the request body could not be decoded (not UTF-8) or Content-Length is malformed",
    "401": "the daemon has an API token and the request lacks 'Authorization: Bearer <token>'",
    "413": "request body larger than the daemon's max_body_bytes",
    "423": "another client holds the control lock (POST /control); send its X-Lidard-Lease",
}


def document_gates(app, token_set: bool = False) -> None:
    """Add the answers of the gates above (400/401/403/413/423) to every mutating operation's OpenAPI entry,
    with the bearer scheme, the lease header and the problem-details body (lidard.api.problems.document).

    The gates are app-wide dependencies and middleware, which FastAPI cannot see per route; a
    client generated from the schema should still know these answers exist and what to send.
    """
    base = app.openapi
    done = False

    def openapi() -> dict[str, Any]:
        nonlocal done
        schema = base()
        if not done:
            for path, ops in schema.get("paths", {}).items():
                for method, op in ops.items():
                    if method.upper() not in MUTATING_METHODS:
                        continue
                    for code, text in _GATE_RESPONSES.items():
                        if code == "423" and path.startswith(router.prefix):
                            text = "the request does not carry the current lease (another client holds it)"
                        op.setdefault("responses", {}).setdefault(code, {"description": text})
                    if "requestBody" in op:  # a body that decodes but does not validate
                        op["responses"].setdefault("422", {"description": "invalid request body"})
            document(schema, mutating=MUTATING_METHODS, lease_header=LEASE_HEADER, token_set=token_set)
            done = True
        return schema

    app.openapi = openapi
