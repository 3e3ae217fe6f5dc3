"""Zenoh messaging: key expressions, stamping, publishers with their QoS, presence.

Key expressions (docs/network.md)::

    bipedtele/<robot_id>/cmd         leader -> follower  Command
    bipedtele/<robot_id>/feedback    follower -> leader  Feedback
    bipedtele/<robot_id>/video       follower -> leader  VideoFrame
    bipedtele/<robot_id>/clock       both                ClockPing / ClockPong
    bipedtele/<robot_id>/status      both                Status
    bipedtele/<robot_id>/presence/<role>/<zid>   liveliness tokens

Control publishers are *express* (no batching delay), ``Priority.REAL_TIME`` and drop on
congestion; the video publisher has a low priority and drops too.

The rest of the transport has a module each: sessions (:func:`open_session`,
:func:`zenoh_config`) in :mod:`bipedtele.link.zenohsession`, the receive path
(:class:`LatestReceiver`, :class:`MessageReceiver`: authentication, decoding, send-time
checks, the gate) in :mod:`bipedtele.link.receivers`. Their names are re-exported here, so
``from bipedtele.link.transport import open_session, LatestReceiver`` keeps working.

Examples
--------
>>> with open_session(cfg.network) as session:                        # doctest: +SKIP
...     keys = Keys(cfg.robot.id)
...     auth = load_message_auth(cfg.network)
...     pubs = Publishers(session, keys, auth=auth)
...     with LatestReceiver(session, keys.cmd, Command, DropCounter("cmd"), SequenceGate(),
...                         auth=auth, max_future_s=cfg.clock.max_future_s) as rx:
...         pubs.feedback.put(fb)
...         got = rx.take()
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import msgspec
import zenoh
from bipedtele.config.profile import ConfigError
from bipedtele.link.acl import access_control_json
from bipedtele.link.auth import MessageAuth
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.messages import Message, encode, new_session_id
from bipedtele.link.receivers import LatestReceiver, MessageReceiver, Received
from bipedtele.link.zenohsession import open_session, zenoh_config

if TYPE_CHECKING:
    from bipedtele.link.session import Handshake

__all__ = [
    "ROLES",
    "Keys",
    "LatestReceiver",
    "LinkError",
    "MessagePublisher",
    "MessageReceiver",
    "PresenceWatcher",
    "Publishers",
    "Received",
    "Stamper",
    "access_control_json",
    "declare_control_publisher",
    "declare_presence",
    "declare_status_publisher",
    "declare_video_publisher",
    "open_session",
    "zenoh_config",
]

LOG = logging.getLogger("bipedtele.link.transport")

ROLES = ("leader", "follower", "router", "monitor")
M = TypeVar("M", bound=Message)


# --------------------------------------------------------------------------- keys


class Keys:
    """Key expressions of one robot: ``bipedtele/<robot_id>/...``.

    Parameters
    ----------
    robot_id : str
        The robot's id (``[robot] id``); must form valid Zenoh key expressions without
        wildcards.

    Raises
    ------
    ConfigError
        If the id makes an invalid key expression.
    """

    def __init__(self, robot_id: str) -> None:
        if not robot_id or any(c in robot_id for c in "/*$?#@ "):
            raise ConfigError(
                f"robot id {robot_id!r}: allowed: a non-empty name without '/', '*', '$', '?', '#', '@' or spaces"
            )
        self.robot_id = robot_id
        self.root = f"bipedtele/{robot_id}"
        for key in (self.cmd, self.feedback, self.video, self.clock, self.status, self.presence("leader")):
            try:
                zenoh.KeyExpr(key)
            except Exception as exc:  # zenoh raises ZError
                raise ConfigError(f"robot id {robot_id!r}: invalid key expression {key!r} ({exc})") from None

    @property
    def cmd(self) -> str:
        """Commands, leader -> follower."""
        return f"{self.root}/cmd"

    @property
    def feedback(self) -> str:
        """Feedback, follower -> leader."""
        return f"{self.root}/feedback"

    @property
    def video(self) -> str:
        """Video frames, follower -> leader."""
        return f"{self.root}/video"

    @property
    def clock(self) -> str:
        """Clock pings and pongs (both directions)."""
        return f"{self.root}/clock"

    @property
    def status(self) -> str:
        """Status messages (both directions)."""
        return f"{self.root}/status"

    def presence(self, role: str) -> str:
        """Prefix of the liveliness tokens of ``role`` (tokens add ``/<zid>``)."""
        if role not in ROLES:
            raise ValueError(f"role {role!r}: allowed: {', '.join(ROLES)}")
        return f"{self.root}/presence/{role}"

    def all(self) -> dict[str, str]:
        """Name -> key of every data key."""
        return {n: getattr(self, n) for n in ("cmd", "feedback", "video", "clock", "status")}

    def __repr__(self) -> str:
        return f"Keys({self.robot_id!r})"


# --------------------------------------------------------------------------- session

# --------------------------------------------------------------------------- publishing


class Stamper:
    """Fills the envelope (sid, seq, send time) of outgoing messages.

    Parameters
    ----------
    sid : int, optional
        Session id; a new random one per process by default.
    clock : callable
        Send-time source [s] (``time.time`` so that receivers on the same host or with
        synced clocks can compute one-way delays).
    """

    def __init__(self, sid: int | None = None, clock: Callable[[], float] = time.time) -> None:
        self.sid = sid if sid is not None else new_session_id()
        self._clock = clock
        # next() on an itertools.count is one C call under the GIL: thread-safe, no lock
        self._next_seq = itertools.count(1).__next__

    def make(self, cls: type[M], **fields: Any) -> M:
        """Return a new message of type ``cls`` with the next seq and the current time."""
        msg: M = cls(sid=self.sid, seq=self._next_seq(), t=self._clock(), **fields)
        return msg

    def restamp(self, msg: M) -> M:
        """Return a copy of ``msg`` with this stamper's sid, the next seq and the current time."""
        out: M = msgspec.structs.replace(msg, sid=self.sid, seq=self._next_seq(), t=self._clock())
        return out


class MessagePublisher:
    """A declared Zenoh publisher that sends :class:`Message` objects.

    Use :func:`declare_control_publisher` or :func:`declare_video_publisher`. With a
    :class:`~bipedtele.link.auth.MessageAuth`, every message is signed (HMAC-SHA256 over the
    encoded message and the key expression).
    """

    def __init__(
        self, publisher: zenoh.Publisher, key: str, auth: MessageAuth | None = None, session: Handshake | None = None
    ) -> None:
        self._pub = publisher
        self._put = publisher.put
        self.key = key
        self.auth = auth
        self.session = session
        self.sent = 0
        self.unsent = 0

    def put(self, msg: Message) -> None:
        """Encode (and sign) and send one message (never blocks: dropped on congestion).

        With a ``session`` (:class:`~bipedtele.link.session.Handshake`) the message is MAC'd with
        the session key, and not sent at all while no handshake completed (``unsent``).
        """
        payload = encode(msg)
        if self.session is not None:
            framed = self.session.sign(payload, self.key)
            if framed is None:
                self.unsent += 1
                return
            payload = framed
        elif self.auth is not None:
            payload = self.auth.sign(payload, self.key)
        self._put(payload)
        self.sent += 1

    def put_bytes(self, payload: bytes) -> None:
        """Send raw bytes as they are, unsigned (tests and tools)."""
        self._pub.put(payload)

    def close(self) -> None:
        """Undeclare the publisher."""
        self._pub.undeclare()

    def __enter__(self) -> MessagePublisher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _declare(
    session: zenoh.Session,
    key: str,
    priority: zenoh.Priority,
    reliability: zenoh.Reliability,
    *,
    express: bool,
) -> zenoh.Publisher:
    """Declare a drop-on-congestion publisher with the given QoS (which picks its link)."""
    return session.declare_publisher(
        key,
        express=express,
        priority=priority,
        congestion_control=zenoh.CongestionControl.DROP,
        reliability=reliability,
    )


def declare_control_publisher(
    session: zenoh.Session, key: str, auth: MessageAuth | None = None, handshake: Handshake | None = None
) -> MessagePublisher:
    """Declare a publisher for control traffic: express, real-time priority, best effort, drop on congestion.

    Best effort: with ``[network] links = "split"`` these messages travel on the control
    link as datagrams, never retransmitted (each one supersedes the previous one;
    :mod:`bipedtele.link.linklayout`). On a single link they travel as before.
    """
    pub = _declare(session, key, zenoh.Priority.REAL_TIME, zenoh.Reliability.BEST_EFFORT, express=True)
    return MessagePublisher(pub, key, auth, handshake)


def declare_status_publisher(session: zenoh.Session, key: str, auth: MessageAuth | None = None) -> MessagePublisher:
    """Declare a publisher for status messages: express, interactive priority, reliable (the status link)."""
    pub = _declare(session, key, zenoh.Priority.INTERACTIVE_LOW, zenoh.Reliability.RELIABLE, express=True)
    return MessagePublisher(pub, key, auth)


def declare_video_publisher(session: zenoh.Session, key: str, auth: MessageAuth | None = None) -> MessagePublisher:
    """Declare a publisher for video: low priority, reliable, drop on congestion (latest-only by nature)."""
    pub = _declare(session, key, zenoh.Priority.DATA_LOW, zenoh.Reliability.RELIABLE, express=False)
    return MessagePublisher(pub, key, auth)


class Publishers:
    """The publishers of one robot's keys, declared on first use.

    Attributes ``cmd``, ``feedback``, ``clock`` (control QoS), ``status`` (status QoS) and ``video``
    (video QoS) are :class:`MessagePublisher` objects. ``close()`` (or leaving the
    ``with`` block) undeclares the ones that were declared.

    Parameters
    ----------
    session : zenoh.Session
    keys : Keys
    auth : MessageAuth, optional
        Signs every message (``[network] message_key_file``, see
        :func:`bipedtele.link.auth.load_message_auth`); video and status with its watch key
        (:func:`bipedtele.link.auth.watch_key`: an observer verifies them without the key).
    handshake : Handshake, optional
        Commands and feedback are MAC'd with its session key instead, and not sent while
        it has none (:mod:`bipedtele.link.session`).
    watch_auth : MessageAuth, optional
        Seals video and status (default: a fresh :meth:`~bipedtele.link.auth.MessageAuth.watch`
        of ``auth``, a watch key of this session's own; a node passes the one whose epoch
        its Hellos announce).
    """

    _CONTROL = ("cmd", "feedback", "clock")
    _SESSION = ("cmd", "feedback")

    def __init__(
        self,
        session: zenoh.Session,
        keys: Keys,
        auth: MessageAuth | None = None,
        handshake: Handshake | None = None,
        watch_auth: MessageAuth | None = None,
    ) -> None:
        self._session = session
        self.keys = keys
        self.auth = auth
        self.watch_auth = watch_auth if watch_auth is not None or auth is None else auth.watch()
        self.handshake = handshake
        self._pubs: dict[str, MessagePublisher] = {}
        self._lock = threading.Lock()

    def _get(self, name: str) -> MessagePublisher:
        pub = self._pubs.get(name)  # declared already: no lock (a dict read is atomic)
        if pub is not None:
            return pub
        with self._lock:
            pub = self._pubs.get(name)
            if pub is None:
                key = getattr(self.keys, name)
                if name == "video":
                    pub = declare_video_publisher(self._session, key, self.watch_auth)
                elif name == "status":
                    pub = declare_status_publisher(self._session, key, self.watch_auth)
                else:
                    hs = self.handshake if name in self._SESSION else None
                    pub = declare_control_publisher(self._session, key, self.auth, hs)
                self._pubs[name] = pub
            return pub

    @property
    def cmd(self) -> MessagePublisher:
        """Publisher of Commands (leader -> follower)."""
        return self._get("cmd")

    @property
    def feedback(self) -> MessagePublisher:
        """Publisher of Feedback (follower -> leader)."""
        return self._get("feedback")

    @property
    def clock(self) -> MessagePublisher:
        """Publisher of Clock pings and pongs."""
        return self._get("clock")

    @property
    def status(self) -> MessagePublisher:
        """Publisher of Status messages."""
        return self._get("status")

    @property
    def video(self) -> MessagePublisher:
        """Publisher of Video frames (video QoS)."""
        return self._get("video")

    def close(self) -> None:
        """Undeclare every declared publisher."""
        with self._lock:
            pubs, self._pubs = list(self._pubs.values()), {}
        for p in pubs:
            p.close()

    def __enter__(self) -> Publishers:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- presence


def declare_presence(session: zenoh.Session, keys: Keys, role: str) -> zenoh.LivelinessToken:
    """Declare this process alive as ``role``; undeclare with the token's ``with`` block.

    The token's key is ``bipedtele/<robot_id>/presence/<role>/<zid>``, so several
    processes of one role do not shadow each other.
    """
    key = f"{keys.presence(role)}/{session.zid()}"
    return session.liveliness().declare_token(key)


class PresenceWatcher:
    """Tracks whether any process of ``role`` is alive (liveliness tokens).

    ``alive`` becomes true when a token appears (including tokens already present when
    the watcher starts) and false when the last one disappears (the peer closed its
    session or its link was lost).
    """

    def __init__(self, session: zenoh.Session, keys: Keys, role: str) -> None:
        self.role = role
        self._alive: set[str] = set()
        self._cond = threading.Condition(threading.Lock())
        self.changes = 0
        self._sub = session.liveliness().declare_subscriber(f"{keys.presence(role)}/*", self._on_sample, history=True)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        with self._cond:
            before = bool(self._alive)
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(key)
            else:
                self._alive.discard(key)
            if bool(self._alive) != before:
                self.changes += 1
                LOG.info("%s %s", self.role, "present" if self._alive else "gone")
            self._cond.notify_all()

    @property
    def alive(self) -> bool:
        """True while at least one process of the role is present."""
        with self._cond:
            return bool(self._alive)

    def wait(self, alive: bool = True, timeout: float = 5.0) -> bool:
        """Wait up to ``timeout`` [s] until ``alive`` has the wanted value; return it."""
        with self._cond:
            return self._cond.wait_for(lambda: bool(self._alive) == alive, timeout)

    def close(self) -> None:
        """Undeclare the liveliness subscriber."""
        self._sub.undeclare()

    def __enter__(self) -> PresenceWatcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
