"""Who may reach the cockpit: Host allow-list, token, websocket Origin, security headers.

The checks are methods of :class:`Access`, a base of
:class:`~bipedtele.leader.cockpit.server.CockpitServer`; a refused request is paced by the
server's :class:`~bipedtele.leader.cockpit.guard.Guard` (:meth:`Access._limited`).

Access
------
The cockpit shows the robot's camera and, with the browser operator, drives the robot, so
every request is checked (``docs/cockpit.md``):

- **Host allow-list.** The ``Host`` header must name this server: the listen address,
  ``localhost``, ``127.0.0.1``, ``[::1]`` or one of ``allowed_hosts``. A web page whose
  name an attacker re-points at this machine (DNS rebinding) sends its own name as Host
  and is refused (403).
- **Per-run token.** A random token (``secrets.token_urlsafe``) is part of the printed
  address, ``http://HOST:PORT/?token=TOKEN``, as notebook servers do. Every request must
  carry it: the ``token`` query parameter, else the cookie the first page load sets
  (``HttpOnly``, ``SameSite=Strict``; the page's scripts, style sheet and websocket then
  carry it). Compared in constant time (:func:`hmac.compare_digest`); missing or wrong: 403.
- **Origin.** A websocket upgrade must carry an ``Origin`` (every browser sends one) whose
  scheme is http(s) and whose host and port are the request's (allowed) ``Host``; no Origin,
  ``null`` or another site's: 403.
- **Client cap.** At most ``max_clients`` websockets at once (each gets every frame, in
  the process that runs the haptic loop); the next one is accepted only to be told
  ``{"type": "refused", "reason": ...}`` and closed with code 1013 ("try again later").
- **Framing and headers.** Every response carries ``Content-Security-Policy`` (same-origin
  scripts, styles and connections, ``frame-ancestors 'none'``), ``X-Frame-Options: DENY``,
  ``X-Content-Type-Options: nosniff`` and ``Referrer-Policy: no-referrer``.

Refusals are counted (:attr:`~bipedtele.leader.cockpit.server.CockpitServer.stats`) and
logged at most once per reason per 5 s.
"""

from __future__ import annotations

import asyncio
import hmac
import time
from collections.abc import Awaitable, Callable
from urllib.parse import urlsplit

from aiohttp import web
from bipedtele.leader.cockpit.guard import (
    Guard,
    GuardedHandler,
    Limits,
)
from bipedtele.link.drops import DropCounter
from bipedtele.recording.foxglovews import parse_host

#: Host names always allowed in the ``Host`` header (loopback).
LOCAL_HOSTS: tuple[str, ...] = ("localhost", "127.0.0.1", "::1")
#: Sent with every response: the page may load only its own files and talk only to this
#: server, and no other site may frame it (clickjacking the joystick).
_SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' blob:; "
        "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'"
    ),
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}
_MIN_TOKEN_LEN = 16
_TOKEN_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_")
_Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


def check_token(token: str) -> str:
    """Return ``token`` if it can be a cockpit token (URL-safe characters, at least 16).

    Raises ValueError naming what is allowed otherwise.
    """
    if len(token) < _MIN_TOKEN_LEN or not set(token) <= _TOKEN_CHARS:
        raise ValueError(f"allowed: at least {_MIN_TOKEN_LEN} characters of A-Z a-z 0-9 - _")
    return token


class Access:
    """The access checks of :class:`~bipedtele.leader.cockpit.server.CockpitServer` (its attributes)."""

    allowed_hosts: frozenset[str]
    token: str
    _token_bytes: bytes
    _port: int
    _counters: dict[str, int]
    _refusals: DropCounter
    guard: Guard | None
    limits: Limits

    @property
    def cookie_name(self) -> str:
        """Name of the token cookie (per port: cookies do not tell ports apart)."""
        return f"bipedtele_cockpit_{self._port}"

    def _refuse(self, counter: str, reason: str, detail: str, text: str) -> web.HTTPForbidden:
        self._counters[counter] += 1
        self._refusals.drop(reason, detail)
        return web.HTTPForbidden(text=f"bipedtele cockpit: {text}\n")

    def _host_ok(self, host: str | None) -> bool:
        parsed = parse_host(host) if host else None
        return parsed is not None and parsed[0] in self.allowed_hosts

    def _token_ok(self, given: str) -> bool:
        try:
            data = given.encode("ascii")
        except UnicodeEncodeError:
            return False
        return hmac.compare_digest(data, self._token_bytes)

    async def _limited(self, request: web.Request, *, bad_token: bool) -> web.StreamResponse | None:
        """Count a refused request (against its address if ``bad_token``); its answer when limited.

        An address locked out by failed tokens (``fail_max`` in ``fail_window_s``) gets 429
        for ``lockout_s`` instead of the reason; beyond the global budget of refusal answers
        the connection is aborted unanswered. None: not limited, the caller refuses with
        the reason.
        """
        guard, addr = self.guard, request.remote or "?"
        if guard is None:
            return None
        now = time.monotonic()
        protocol = request.protocol
        if not guard.may_answer(now):
            if isinstance(protocol, GuardedHandler):
                protocol.hold(self.limits.hold_s)  # no answer: it waits, and guesses no more
            await asyncio.sleep(self.limits.hold_s + 1.0)  # closed before: never answered
            return web.Response(status=429)
        if bad_token and guard.locked(addr, now):
            guard.counters["refused_rate"] += 1
            self._refusals.drop("rate_limited", addr)
            if isinstance(protocol, GuardedHandler):
                protocol.hold(self.limits.hold_s)  # this answer, then nothing more for a while
            return web.Response(
                status=429,
                text="bipedtele cockpit: too many refused requests; try again later\n",
                headers={"Retry-After": str(round(self.limits.lockout_s))},
            )
        if bad_token and guard.failed(addr, now):
            self._refusals.drop("locked_out", f"{addr} for {self.limits.lockout_s:g} s")
        return None

    @web.middleware
    async def _guard(self, request: web.Request, handler: _Handler) -> web.StreamResponse:
        """Host allow-list and token on every request; sets the token cookie.

        A request with the right Host and token is always served; the others count against
        their address (:meth:`_limited`).
        """
        host = request.headers.get("Host")
        in_query = request.query.get("token")
        given = in_query if in_query is not None else request.cookies.get(self.cookie_name)
        host_ok, token_ok = self._host_ok(host), bool(given) and self._token_ok(given or "")
        if not (host_ok and token_ok):
            limited = await self._limited(request, bad_token=not token_ok)
            if limited is not None:
                return limited
        if not host_ok:
            raise self._refuse(
                "refused_host",
                "bad_host",
                f"Host {str(host)[:80]!r} from {request.remote}",
                "this Host is not allowed (allowed: the listen address, localhost, 127.0.0.1, [::1] "
                "and leader.cockpit_allowed_hosts)",
            )
        if not token_ok:
            raise self._refuse(
                "refused_token",
                "bad_token" if given else "no_token",
                f"{request.path} from {request.remote}",
                "open the address the leader printed: http://HOST:PORT/?token=TOKEN",
            )
        if isinstance(request.protocol, GuardedHandler):
            request.protocol.trust()  # the token holder's connection is never closed to make room
        response = await handler(request)
        if in_query is not None and not response.prepared:
            response.set_cookie(self.cookie_name, self.token, httponly=True, samesite="Strict", path="/")
        return response

    async def _add_headers(self, request: web.Request, response: web.StreamResponse) -> None:
        for key, value in _SECURITY_HEADERS.items():
            response.headers.setdefault(key, value)

    def _origin_ok(self, request: web.Request) -> bool:
        """Tell whether the websocket's Origin is this very server as the browser reached it.

        That is the Host header, already on the allow-list: scheme http(s), same host
        and port.
        """
        origin = request.headers.get("Origin")
        if not origin:
            return False
        try:
            parts = urlsplit(origin)
        except ValueError:
            return False
        if parts.scheme not in ("http", "https") or parts.path not in ("", "/") or parts.query:
            return False
        got, want = parse_host(parts.netloc), parse_host(request.headers.get("Host", ""))
        if got is None or want is None or got[0] not in self.allowed_hosts:
            return False
        default = 443 if parts.scheme == "https" else 80
        return got[0] == want[0] and (got[1] or default) == (want[1] or default)
