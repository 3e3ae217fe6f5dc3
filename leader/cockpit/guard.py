"""What keeps the cockpit from being starved: timeouts, caps, a failed-request limit, quiet logs.

Everything here runs in the cockpit's asyncio loop (one thread), so nothing is locked.

- :class:`Limits`: the figures (``docs/cockpit.md``).
- :func:`descriptor_budget`: raise the soft descriptor limit to the hard one and size the
  total connection cap from what is left, keeping a reserve for everything else.
- :class:`Guard`: connections per address and in total (beyond, the oldest connection that
  has not shown the token yet is closed to make room, else the new one is refused), failed
  requests per address (after ``fail_max`` in ``fail_window_s`` an address gets 429 for
  ``lockout_s``) and a global budget of refusal answers per second (beyond it a refused
  request is closed without an answer).
- :func:`accept_loop`: accepts connections and applies the caps before aiohttp sees them.
- :class:`GuardedHandler`: aiohttp's connection protocol with a deadline for its first
  complete request head, and :meth:`~GuardedHandler.hold` for guessers.
- :class:`Throttle`: a logging filter, one line per kind per interval with a count and
  no traceback (a flood must not fill the disk with tracebacks).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import socket
import struct
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from aiohttp.web_protocol import RequestHandler

__all__ = ["ERR_LOG", "Guard", "GuardedHandler", "Limits", "Throttle", "accept_loop", "descriptor_budget"]

LOG = logging.getLogger("bipedtele.leader.cockpit")
#: Errors of the server's loop and of aiohttp: one line per kind per interval (:class:`Throttle`).
ERR_LOG = logging.getLogger("bipedtele.leader.cockpit.errors")


@dataclass(frozen=True)
class Limits:
    """The cockpit's limits (times in seconds)."""

    header_timeout_s: float = 5.0  #: a connection's first complete request head, at the latest
    idle_timeout_s: float = 15.0  #: an idle keep-alive connection is closed after this
    per_address: int = 32  #: connections at once from one client address
    total: int = 256  #: connections at once in all (lowered by :func:`descriptor_budget`)
    fail_max: int = 10  #: refused requests of one address in ``fail_window_s`` that lock it
    fail_window_s: float = 10.0
    lockout_s: float = 30.0  #: how long a locked address gets 429 (unless it has the token)
    refusals_per_s: float = 50.0  #: refusal answers (403, 429) per second in all; beyond: held
    refused_connections_per_s: float = 2000.0  #: beyond, accepting pauses (the backlog waits)
    refused_locked_per_s: float = 50.0  #: the same for a locked address (a guesser reconnecting)
    hold_s: float = 5.0  #: a guesser's connection is held this long (unanswered) after a 429
    descriptor_reserve: int = 256  #: descriptors kept for the rest of the process
    log_interval_s: float = 10.0  #: one log line per kind of error per interval


def descriptor_budget(limits: Limits) -> tuple[int, dict[str, int]]:
    """Raise the soft ``RLIMIT_NOFILE`` to the hard limit; return the total cap and the figures.

    The cap is ``limits.total`` or half of the descriptors left after those in use and
    ``descriptor_reserve``, whichever is smaller (at least 8).
    """
    try:
        import resource  # POSIX only
    except ImportError:  # Windows: no descriptor limit to raise; sockets are handles
        cap = max(8, min(limits.total, 4096))
        return cap, {"nofile_soft": 0, "descriptors_used": 0, "total_cap": cap}
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = 65536 if hard == resource.RLIM_INFINITY else hard
    if soft != resource.RLIM_INFINITY and soft < want:
        with contextlib.suppress(ValueError, OSError):
            resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
            soft = want
    try:
        used = len(os.listdir("/proc/self/fd"))
    except OSError:  # pragma: no cover - not Linux
        used = 64
    limit = 1 << 20 if soft == resource.RLIM_INFINITY else soft
    free = limit - used - limits.descriptor_reserve
    cap = max(8, min(limits.total, free // 2))
    return cap, {"nofile_soft": int(limit), "descriptors_used": used, "total_cap": cap}


class Guard:
    """Connection caps and the failed-request limit (one asyncio loop; no locks)."""

    def __init__(self, limits: Limits | None = None, total_cap: int | None = None) -> None:
        self.limits = limits or Limits()
        self.total_cap = self.limits.total if total_cap is None else total_cap
        self.per_address: dict[str, int] = {}
        self.total = 0
        self._fails: dict[str, deque[float]] = {}
        self._locked_until: dict[str, float] = {}
        self._budget = self.limits.refusals_per_s
        self._budget_t = time.monotonic()
        # connections that have not shown the token yet, oldest first: the first to go at a cap
        self.untrusted: dict[Any, str] = {}
        self.counters = {
            "refused_conn_address": 0,
            "refused_conn_total": 0,
            "closed_no_head": 0,
            "refused_rate": 0,
            "closed_unanswered": 0,
            "lockouts": 0,
            "evicted_untrusted": 0,
        }

    # -- connections

    def admit(self, addr: str) -> str | None:
        """Count a new connection from ``addr``; the cap it hits (and is refused by) or None."""
        if self.total >= self.total_cap:
            self.counters["refused_conn_total"] += 1
            return "too_many_connections"
        n = self.per_address.get(addr, 0)
        if n >= self.limits.per_address:
            self.counters["refused_conn_address"] += 1
            return "too_many_from_address"
        self.per_address[addr] = n + 1
        self.total += 1
        return None

    def release(self, addr: str) -> None:
        """Uncount a connection admitted by :meth:`admit` (it closed)."""
        n = self.per_address.get(addr, 0) - 1
        if n > 0:
            self.per_address[addr] = n
        else:
            self.per_address.pop(addr, None)
        self.total = max(0, self.total - 1)

    def make_room(self, why: str, addr: str) -> bool:
        """Close the oldest connection without the token (of ``addr`` at its cap); True when one went.

        So the token holder always gets in, whatever connections without it hold: a cap
        they fill is made room in by closing the oldest of them, not by refusing newcomers.
        """
        victim = next((h for h, a in self.untrusted.items() if why == "too_many_connections" or a == addr), None)
        if victim is None:
            return False
        self.counters["evicted_untrusted"] += 1
        victim.evict()
        return True

    # -- refused requests

    def locked(self, addr: str, now: float | None = None) -> bool:
        """Tell whether ``addr`` is locked out (too many refused requests lately)."""
        until = self._locked_until.get(addr)
        if until is None:
            return False
        if (time.monotonic() if now is None else now) < until:
            return True
        del self._locked_until[addr]
        return False

    def failed(self, addr: str, now: float | None = None) -> bool:
        """Count a refused request of ``addr``; True when this one locks the address."""
        now = time.monotonic() if now is None else now
        q = self._fails.setdefault(addr, deque())
        q.append(now)
        while q and now - q[0] > self.limits.fail_window_s:
            q.popleft()
        if len(q) < self.limits.fail_max:
            return False
        q.clear()
        self._locked_until[addr] = now + self.limits.lockout_s
        self.counters["lockouts"] += 1
        if len(self._fails) > 10_000:  # many addresses: forget the quiet ones
            self._fails = {a: d for a, d in self._fails.items() if d}
        return True

    def may_answer(self, now: float | None = None) -> bool:
        """Take one refusal answer from the global budget (token bucket); False when spent."""
        now = time.monotonic() if now is None else now
        rate = self.limits.refusals_per_s
        self._budget = min(rate, self._budget + (now - self._budget_t) * rate)
        self._budget_t = now
        if self._budget >= 1.0:
            self._budget -= 1.0
            return True
        self.counters["closed_unanswered"] += 1
        return False


async def accept_loop(
    listener: socket.socket,
    guard: Guard,
    factory: Callable[[str], asyncio.Protocol],
    on_refuse: Callable[[str, str], None],
) -> None:
    """Accept connections, applying the caps before any protocol or transport is made.

    At a cap, the oldest connection that has not shown the token is closed to make room
    (:meth:`Guard.make_room`); when there is none, the new connection is reset at once
    (``SO_LINGER`` 0: its descriptor is free now). While more than ``refused_connections_per_s`` are refused in a second (or
    ``refused_locked_per_s`` for a locked address), accepting pauses after each refusal:
    a connect flood then waits in the kernel's backlog, and its sender with it, instead of
    taking the machine's CPU.
    """
    loop = asyncio.get_running_loop()
    linger0 = struct.pack("ii", 1, 0)
    window_t, refused = loop.time(), 0

    async def pace(addr: str) -> None:
        """Count one refusal (or one eviction) and pause accepting when they come too fast."""
        nonlocal window_t, refused
        now = loop.time()
        if now - window_t >= 1.0:
            window_t, refused = now, 0
        refused += 1
        # A guesser's (locked address) reconnect storm waits in the backlog sooner.
        rate = guard.limits.refused_locked_per_s if guard.locked(addr) else guard.limits.refused_connections_per_s
        if refused > rate:
            await asyncio.sleep(1.0 / rate)

    while True:
        try:
            conn, peer = await loop.sock_accept(listener)
        except OSError as exc:  # EMFILE and the like: logged (throttled), retried shortly
            ERR_LOG.error(f"cockpit: accept failed: {type(exc).__name__}: {exc}")
            await asyncio.sleep(0.1)
            continue
        addr = str(peer[0]) if isinstance(peer, tuple) and peer else "?"
        why = guard.admit(addr)
        evicted = why is not None and guard.make_room(why, addr)
        if evicted:
            why = guard.admit(addr)
        if why is None:
            conn.setblocking(False)
            try:
                await loop.connect_accepted_socket(lambda addr=addr: factory(addr), conn)  # type: ignore[misc]
            except OSError:
                guard.release(addr)
                conn.close()
            if evicted:  # room made by closing another: paced as a refusal, or a flood cycles at full speed
                await pace(addr)
            continue
        with contextlib.suppress(OSError):
            conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, linger0)
        conn.close()
        on_refuse(why, addr)
        await pace(addr)


class GuardedHandler(RequestHandler):
    """aiohttp's connection protocol, with a header deadline and holding.

    Made by :func:`accept_loop` for an admitted connection (released when it closes). One
    that has not sent a complete request head within ``header_timeout_s`` is closed.
    (Idle keep-alive connections are closed by aiohttp's ``keepalive_timeout``, set to
    ``idle_timeout_s``.) :meth:`hold` stops reading a connection and closes it later:
    a guesser waits for an answer that does not come instead of guessing again.
    """

    def __init__(self, manager: Any, *, guard: Guard, addr: str, **kwargs: Any) -> None:
        super().__init__(manager, **kwargs)
        self._guard = guard
        self._addr = addr
        self._admitted = True
        self._lost = False
        self._held = False
        self._head_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:  # noqa: D102
        super().connection_made(transport)
        self._guard.untrusted[self] = self._addr
        self._head_timer = self._loop.call_later(self._guard.limits.header_timeout_s, self._no_head)

    def data_received(self, data: bytes) -> None:  # noqa: D102
        if self._held:
            return
        super().data_received(data)
        if self._head_timer is not None and self._request_count:
            self._head_timer.cancel()
            self._head_timer = None

    def trust(self) -> None:
        """Mark the connection as the token holder's: never closed to make room."""
        self._guard.untrusted.pop(self, None)

    def evict(self) -> None:
        """Uncount this connection now and close it (room for one that may hold the token)."""
        self._release()
        if self.transport is not None:
            self.transport.abort()

    def hold(self, seconds: float) -> None:
        """Ignore what this connection sends from now on; close it in ``seconds``."""
        self._held = True
        self._loop.call_later(seconds, self._abort)

    def _abort(self) -> None:
        if self.transport is not None:
            self.transport.abort()

    def _no_head(self) -> None:
        self._head_timer = None
        if not self._request_count and self.transport is not None:
            self._guard.counters["closed_no_head"] += 1
            self.transport.abort()

    def _release(self) -> None:
        self._guard.untrusted.pop(self, None)
        if self._admitted:
            self._admitted = False
            self._guard.release(self._addr)

    def connection_lost(self, exc: BaseException | None) -> None:  # noqa: D102
        if self._lost:
            return
        self._lost = True
        self._release()
        if self._head_timer is not None:
            self._head_timer.cancel()
            self._head_timer = None
        super().connection_lost(exc)


class Throttle(logging.Filter):
    """Let through one record per kind per ``interval_s``, with the count, never a traceback.

    The kind is the logger's name and the message template (``record.msg``); a record let
    through says how many of its kind were held back since the last one.
    """

    def __init__(self, interval_s: float = 10.0) -> None:
        super().__init__()
        self.interval_s = interval_s
        self._last: dict[tuple[str, str], float] = {}
        self._held: dict[tuple[str, str], int] = {}

    def filter(self, record: logging.LogRecord) -> bool:  # noqa: D102
        kind = (record.name, str(record.msg)[:200])
        now = time.monotonic()
        last = self._last.get(kind)
        if last is not None and now - last < self.interval_s:
            self._held[kind] = self._held.get(kind, 0) + 1
            return False
        self._last[kind] = now
        held = self._held.pop(kind, 0)
        if record.exc_info and record.exc_info[1] is not None:
            exc = record.exc_info[1]
            record.msg = f"{record.getMessage()}: {type(exc).__name__}: {exc}"
            record.args = None
        record.exc_info, record.exc_text, record.stack_info = None, None, None
        if held:
            record.msg = f"{record.getMessage()} (and {held} more like it in the last {self.interval_s:g} s)"
            record.args = None
        if len(self._last) > 1000:
            self._last.clear()
        return True
