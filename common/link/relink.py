"""Links that heal: a client session reopened in place when its control link is lost or silent.

With ``[network] links = "split"`` a client's session holds three links to its router
(:mod:`bipedtele.link.linklayout`); commands, feedback and clock travel on the UDP one. Zenoh's
UDP link carries no authentication below the session: one datagram with the router's
address as its source can end it. Measured on Zenoh 1.10:

- a forged Close (``23 00``, "close the session") to the client's UDP port: the client's
  session to the router ends, and Zenoh reconnects it with **one** link only (a client
  reopens the first endpoint of its group, never a lost link of a multi-link session),
  while the router keeps the old UDP link, on which nothing carries a lease: the router
  sends the control traffic into it and the robot never hears a command again;
- any undecodable datagram to the router's UDP port from the client's address: the router
  drops that link and tells the client, and control moves onto a TLS link, silently.

:class:`RelinkSession` wraps a client session: every declaration made through it
(publishers, subscribers, liveliness tokens and subscribers) is made again on a new
session when it reopens. A watcher thread reopens it, with one WARNING line naming the
cause, when

- the control link (the link that carries priority 1, real time) is not the one the layout
  asks for (``udp`` for ``split``) for :attr:`RelinkSession.grace_s` while a session to the
  router exists (a lost or moved control link, or a session Zenoh reopened with one link);
- the peer is present but no authenticated control message (command, feedback, clock;
  the node calls :meth:`RelinkSession.heard`) arrived for ``silence_s`` (a link that is
  up at both ends but carries nothing, e.g. a router that sends into a stale UDP link).

Reopening closes the old session first (its tokens and subscribers go with it), then
opens a new one and declares everything again. A failed reopen is retried with a doubling
wait. The robot stops on its watchdog meanwhile; it walks again on the next command.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.linklayout import CONTROL_PRIORITIES

__all__ = [
    "CONTROL_CODES",
    "RELINK_SILENCE_S",
    "RelinkSession",
    "control_code",
    "control_link",
    "control_name",
    "describe_control",
    "relink_control",
]

LOG = logging.getLogger("bipedtele.link.relink")

#: The peer present and no authenticated control message for this long [s]: the session is
#: reopened (the leader commands and the follower answers at tens of Hz; clock pings at 4 Hz).
RELINK_SILENCE_S = 1.0

#: Zenoh's real-time priority: the control traffic's (commands, feedback, clock).
_CONTROL_PRIORITY = 1
#: The priority range of the control link of the split layouts.
_CONTROL_RANGE = tuple(int(p) for p in CONTROL_PRIORITIES.split("-"))


#: The control link in a Status counter (``control_link``): 0 no router, 1 its own UDP link,
#: 2 its own TCP/TLS link (``split-tcp``), 3 a link shared with other traffic (``single``, or
#: control moved onto the status link).
CONTROL_CODES: dict[str, int] = {"none": 0, "udp": 1, "tls": 2, "tcp": 2, "shared": 3}


def control_code(described: str) -> int:
    """Return the ``control_link`` counter of a :func:`describe_control` text."""
    return CONTROL_CODES["shared"] if described.endswith("(shared)") else CONTROL_CODES.get(described, 3)


def control_name(code: int) -> str:
    """Return the words of a ``control_link`` counter (the fleet view)."""
    return {0: "no router", 1: "udp", 2: "tcp/tls", 3: "shared link"}.get(code, "?")


def relink_control(net: NetworkConfig) -> str:
    """Return the control link's protocol a client of ``net`` must keep (``""``: nothing to watch).

    ``split``: ``udp``; ``split-tcp``: the endpoint's own (``tls``, ``tcp``); ``single``, a
    router or a peer, or endpoints of other protocols: ``""``.
    """
    if net.mode != "client" or not net.connect or net.links == "single":
        return ""
    proto = net.connect[0].partition("/")[0]
    if proto not in ("tcp", "tls"):
        return ""
    return "udp" if net.links == "split" else proto


def control_link(links: list[Any]) -> Any | None:
    """Return the link that carries priority 1 (real time, best effort) among ``links`` (None: none).

    As Zenoh picks it: a link whose priority range holds 1 (a link without a range holds
    every priority), a best-effort one first, then the narrowest range.
    """
    best, best_score = None, (2, 99)
    for link in links:
        prio = link.priorities
        lo, hi = (0, 7) if prio is None else (prio[0], prio[1])
        if not lo <= _CONTROL_PRIORITY <= hi:
            continue
        score = (0 if link.reliability == zenoh.Reliability.BEST_EFFORT else 1, hi - lo)
        if score < best_score:
            best, best_score = link, score
    return best


def describe_control(links: list[Any]) -> str:
    """Return the control link's protocol (``udp``, ``tls``, ``tcp``...; ``none``: no link).

    A link of its own (the layout's priority range) is named bare; a link it shares with
    other traffic as ``PROTO (shared)``: control moved onto the status or the only link.
    """
    link = control_link(links)
    if link is None:
        return "none"
    proto = str(link.dst).partition("/")[0]
    own = link.priorities is not None and tuple(link.priorities) == _CONTROL_RANGE
    return proto if own else f"{proto} (shared)"


class _FakeSample:
    """A liveliness DELETE for a token that vanished while the session was being reopened."""

    kind = zenoh.SampleKind.DELETE

    def __init__(self, key_expr: str) -> None:
        self.key_expr = key_expr


class _Declared:
    """One declaration: made again on every new session."""

    def __init__(self, owner: RelinkSession, make: Callable[[zenoh.Session], Any]) -> None:
        self._owner = owner
        self._make = make
        self.obj: Any = None  # made by RelinkSession.add, on the current session
        self.closed = False

    def redeclare(self, session: zenoh.Session) -> None:
        self.obj = self._make(session)

    def __enter__(self) -> _Declared:
        return self

    def __exit__(self, *exc: object) -> None:
        self.undeclare()

    def undeclare(self) -> None:
        """Undeclare it for good (it is not made again)."""
        self.closed = True
        self._owner.forget(self)
        with contextlib.suppress(zenoh.ZError):  # its session may be closed already
            self.obj.undeclare()


class _Publisher(_Declared):
    def put(self, payload: Any, **kwargs: Any) -> None:
        with contextlib.suppress(zenoh.ZError):  # a session being reopened: lost, as on a lost link
            self.obj.put(payload, **kwargs)


class _Token(_Declared):
    pass


class _LivelinessSubscriber(_Declared):
    """Tracks the live tokens it reported, to report those that vanished during a reopen."""

    def __init__(self, owner: RelinkSession, key: str, handler: Callable[[Any], None], history: bool) -> None:
        self._handler = handler
        self.alive: set[str] = set()
        self._seen: set[str] = set()
        self._lock = threading.Lock()
        super().__init__(owner, lambda s: s.liveliness().declare_subscriber(key, self._on, history=history))

    def _on(self, sample: Any) -> None:
        key = str(sample.key_expr)
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self.alive.add(key)
                self._seen.add(key)
            else:
                self.alive.discard(key)
        self._handler(sample)

    def redeclare(self, session: zenoh.Session) -> None:
        with self._lock:
            self._seen.clear()
        super().redeclare(session)

    def settle(self) -> None:
        """Report as gone the tokens the new session's history did not show again."""
        with self._lock:
            gone = self.alive - self._seen
            self.alive -= gone
        for key in sorted(gone):
            self._handler(_FakeSample(key))


class _Liveliness:
    def __init__(self, owner: RelinkSession) -> None:
        self._owner = owner

    def declare_token(self, key: str) -> _Token:
        owner = self._owner
        zid = str(owner.current.zid())

        def make(s: zenoh.Session) -> Any:  # the key names the session: the new one's
            return s.liveliness().declare_token(key.replace(zid, str(s.zid())))

        return owner.add(_Token(owner, make))

    def declare_subscriber(self, key: str, handler: Callable[[Any], None], *, history: bool = False) -> Any:
        return self._owner.add(_LivelinessSubscriber(self._owner, key, handler, history))


class RelinkSession:
    """A client's Zenoh session that reopens itself when its control link is lost (module docstring).

    Parameters
    ----------
    opener : callable
        Opens a new session (:func:`bipedtele.link.zenohsession.open_session`'s work); may raise.
    control : str
        The control link's protocol the layout asks for (``udp`` for ``split``, ``tls`` or
        ``tcp`` for ``split-tcp``); ``""``: no link check (``single``).
    silence_s : float
        The peer present and no authenticated control message for this long [s]: reopen.
        0: no silence check.
    grace_s : float
        A wrong or missing control link is tolerated this long [s] (a session opening).
    peer_present : callable, optional
        True while the peer (the leader for a follower, and so on) is present.
    """

    def __init__(
        self,
        opener: Callable[[], zenoh.Session],
        *,
        control: str,
        silence_s: float = 2.0,
        grace_s: float = 0.5,
        peer_present: Callable[[], bool] | None = None,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self._opener = opener
        self.current: zenoh.Session = opener()
        self.control = control
        self.silence_s = silence_s
        self.grace_s = grace_s
        self.peer_present = peer_present
        self._mono = monotonic
        self._decls: list[_Declared] = []
        self._lock = threading.RLock()  # the declarations, and the swap of sessions
        self._cause = ""  # set by a link event, taken by the watcher
        self._wake = threading.Event()
        self._done = threading.Event()
        self.reopens = 0
        self._heard_at: float | None = None
        self._status_first: float | None = None  # the peer's status since the last control message
        self._status_last = -float("inf")
        self._wrong_since: float | None = None
        self._base_s = max(1.0, silence_s)
        self._wait_s = self._base_s
        self._not_before = 0.0
        self._last_reopen = -float("inf")
        self._backoff_s = 0.0
        self._listeners: list[Any] = []
        self._listen(self.current)
        self._thread = threading.Thread(target=self._run, name="relink", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ zenoh.Session's surface

    def zid(self) -> Any:
        """Return the current session's Zenoh id."""
        return self.current.zid()

    @property
    def info(self) -> Any:
        """The current session's info (links, transports)."""
        return self.current.info

    def declare_publisher(self, key: str, **kwargs: Any) -> _Publisher:
        """Declare a publisher, declared again on every new session."""
        return self.add(_Publisher(self, lambda s: s.declare_publisher(key, **kwargs)))

    def declare_subscriber(self, key: str, handler: Callable[[Any], None], **kwargs: Any) -> _Declared:
        """Declare a subscriber, declared again on every new session."""
        return self.add(_Declared(self, lambda s: s.declare_subscriber(key, handler, **kwargs)))

    def liveliness(self) -> _Liveliness:
        """Liveliness tokens and subscribers declared again on every new session."""
        return _Liveliness(self)

    def close(self) -> None:
        """Stop watching and close the session."""
        self._done.set()
        self._wake.set()
        if self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._close_session(self.current)

    # ------------------------------------------------------------------ bookkeeping

    def add(self, decl: Any) -> Any:
        """Declare ``decl`` on the current session and keep it to declare again on the next; return it."""
        with self._lock:  # not while a reopen swaps the sessions
            decl.redeclare(self.current)
            self._decls.append(decl)
        return decl

    def forget(self, decl: _Declared) -> None:
        """Stop declaring ``decl`` again (it was undeclared)."""
        with self._lock:
            if decl in self._decls:
                self._decls.remove(decl)

    def heard(self) -> None:
        """Note an authenticated control message (called from Zenoh callbacks: cheap)."""
        self._heard_at = self._mono()
        self._status_first = None

    def heard_status(self) -> None:
        """Note an authenticated status message of the peer (it travels on the status link)."""
        now = self._mono()
        if self._status_first is None:
            self._status_first = now
        self._status_last = now

    def control_now(self) -> str:
        """Return the protocol of the link that carries control now (``none``: no session to the router)."""
        try:
            return describe_control(list(self.current.info.links()))
        except zenoh.ZError:
            return "none"

    # ------------------------------------------------------------------ watching

    def _listen(self, session: zenoh.Session) -> None:
        def on_link(event: Any) -> None:
            link, prio = event.link, event.link.priorities
            if event.kind == zenoh.SampleKind.DELETE and prio and prio[0] <= _CONTROL_PRIORITY <= prio[1]:
                self._cause = (
                    f"control link {str(link.dst).partition('?')[0]} closed while the session stayed up "
                    "(a Close or an undecodable datagram: an unauthenticated packet?)"
                )
                self._wake.set()

        def on_transport(event: Any) -> None:
            if event.kind == zenoh.SampleKind.DELETE and not self._done.is_set():
                self._cause = "the session to the router was closed (a forged Close on UDP, or the router restarted?)"

        try:
            self._listeners = [
                session.info.declare_link_events_listener(on_link, history=False),
                session.info.declare_transport_events_listener(on_transport, history=False),
            ]
        except zenoh.ZError as exc:
            LOG.debug("no link events: %s", exc)

    def _run(self) -> None:
        while not self._done.is_set():
            self._wake.wait(0.1)
            self._wake.clear()
            if self._done.is_set():
                return
            try:
                cause = self._due()
                if cause:
                    self.reopen(cause)
            except Exception:  # a bad moment must not end the watcher
                LOG.exception("relink: unexpected error; watching on")

    def _due(self) -> str:
        """Return the cause to reopen the session now, or ``""``."""
        now = self._mono()
        if now < self._not_before:
            return ""
        if self.control and self._has_router():
            got = self.control_now()
            if got == self.control:
                self._wrong_since = None
            else:
                self._wrong_since = self._wrong_since if self._wrong_since is not None else now
                if now - self._wrong_since >= self.grace_s:
                    return self._cause or f"control link is {got}, not {self.control}"
        heard = self._heard_at
        if heard is not None and heard > self._last_reopen:
            self._wait_s = self._base_s  # traffic resumed after the last reopen
        if self.silence_s > 0 and heard is not None and now - heard >= self._wait_s and self._status_flows(now):
            return f"control link silent for {now - heard:.1f} s while the peer's status arrives"
        return ""

    def _status_flows(self, now: float) -> bool:
        """Whether the peer is present and its status kept arriving for about a second (2 Hz: three of them).

        A path that is down carries neither (nothing to reopen); after an outage the status
        link's backlog arrives in one burst, before the control link's first datagram.
        """
        first, last = self._status_first, self._status_last
        present = self.peer_present is None or self.peer_present()
        return present and first is not None and last - first >= 0.9 and now - last < 1.0

    def _has_router(self) -> bool:
        try:
            return any(True for _ in self.current.info.transports())
        except zenoh.ZError:
            return False

    def reopen(self, cause: str) -> bool:
        """Close the session and open a new one with every declaration; one log line. False: not now."""
        old = self.current
        try:
            new = self._opener()
        except Exception as exc:
            self._not_before = self._mono() + self._wait_s
            LOG.warning("%s: cannot reopen the session yet (%s); retrying in %.0f s", cause, exc, self._wait_s)
            self._wait_s = min(30.0, self._wait_s * 2.0)
            return False
        if self._done.is_set():  # closed meanwhile
            with contextlib.suppress(zenoh.ZError):
                new.close()
            return False
        with self._lock:
            self._close_session(old)
            self.current = new
            for d in list(self._decls):
                try:
                    d.redeclare(new)
                except zenoh.ZError as exc:
                    LOG.warning("relink: cannot declare again on the new session: %s", exc)
            self._listen(new)
        self.reopens += 1
        self._cause = ""
        self._wrong_since = None
        now = self._mono()
        # silence counts from now; another silence reopen only after twice as long, unless
        # traffic resumes in between
        self._heard_at = now if self._heard_at is not None else None
        # reopens in a row (a path that will not carry UDP): each waits twice as long, up to 30 s
        self._backoff_s = min(30.0, max(1.0, 2.0 * self._backoff_s)) if now - self._last_reopen < 30.0 else 0.0
        self._last_reopen = now
        self._wait_s = min(30.0, self._wait_s * 2.0)
        self._not_before = now + max(self.grace_s, self._backoff_s)
        LOG.warning("%s: session reopened (reopen %d), control on %s", cause, self.reopens, self.control_now())
        settle = threading.Timer(1.0, self._settle)
        settle.daemon = True
        settle.start()
        return True

    def _settle(self) -> None:
        with self._lock:
            subs = [d for d in self._decls if isinstance(d, _LivelinessSubscriber)]
        for s in subs:
            s.settle()

    def _close_session(self, session: zenoh.Session) -> None:
        for listener in self._listeners:
            with contextlib.suppress(zenoh.ZError):
                listener.undeclare()
        self._listeners = []
        with contextlib.suppress(zenoh.ZError):
            session.close()
