"""Zenoh transport: session from ``[network]``, key expressions, QoS, receivers, presence.

Key expressions (docs/network.md)::

    bipedtele/<robot_id>/cmd         leader -> follower  Command
    bipedtele/<robot_id>/feedback    follower -> leader  Feedback
    bipedtele/<robot_id>/video       follower -> leader  VideoFrame
    bipedtele/<robot_id>/clock       both                ClockPing / ClockPong
    bipedtele/<robot_id>/status      both                Status
    bipedtele/<robot_id>/presence/<role>/<zid>   liveliness tokens

Control publishers are *express* (no batching delay), ``Priority.REAL_TIME`` and drop on
congestion; the video publisher has a low priority and drops too. Loops read the newest
message only (:class:`LatestReceiver`, a ring of one); clock pongs, where every message
matters, go through the queue-style :class:`MessageReceiver`.

Receivers never raise on bad input. In order, a payload is dropped and counted in a
:class:`~bipedtele.drops.DropCounter` when: it fails authentication (``no_mac``,
``bad_mac``; with a :class:`~bipedtele.auth.MessageAuth`, checked before anything is
decoded; without one, a signed payload is ``mac_unexpected``), it fails :func:`bipedtele.messages.decode` (the
:class:`~bipedtele.messages.MessageError` reason), its send time is more than
``max_future_s`` ahead of the local clock (``future``) or the peer clock's offset is not
known yet (``clock_not_synced``), it was sent longer ago than ``max_age_s`` (``too_old``,
before the gate: an old replay never binds it), or an optional :class:`~bipedtele.gate.SequenceGate`
refuses it. Delay estimators never see a negative delay.

Sessions: :func:`open_session` reads only the settings of the process's role; a client
that cannot reach its router raises :class:`LinkError` saying which failure it is
(:mod:`bipedtele.linkcheck`).

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

import functools
import itertools
import json
import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar, cast

import msgspec
import zenoh
from bipedtele.acl import access_control_json, credential_users
from bipedtele.auth import UNEXPECTED_MAC_LINE, MacError, MessageAuth, is_signed
from bipedtele.clock import ClockSync, DelayEstimator
from bipedtele.config import ConfigError
from bipedtele.drops import DropCounter
from bipedtele.gate import SequenceGate
from bipedtele.linkcheck import STEP_TIMEOUT_S, LinkError, check_endpoint
from bipedtele.linklayout import MAX_LINKS, client_endpoints, router_listen_endpoints
from bipedtele.messages import (
    MAX_JPEG_BYTES,
    Message,
    MessageError,
    VideoFrame,
    decode,
    encode,
    new_session_id,
)
from bipedtele.sections import NetworkConfig

if TYPE_CHECKING:
    from bipedtele.session import Handshake

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

LOG = logging.getLogger("bipedtele.transport")

ROLES = ("leader", "follower", "router", "monitor")
M = TypeVar("M", bound=Message)

#: A client's session must open within this many round trips of its router...
OPEN_RTTS = 8.0
#: ...and at least this long [s] (after the endpoint checks passed).
OPEN_MIN_S = 3.0
#: Session handshakes tried before giving up, each given twice the time of the one before.
OPEN_TRIES = 2
#: A refused connection (a router still starting) is retried this long [s].
REFUSED_RETRY_S = 4.0


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


def _read_password(net: NetworkConfig) -> str:
    if net.password_file:
        try:
            return Path(net.password_file).read_text(encoding="utf-8").strip()
        except OSError as exc:
            raise ConfigError(
                f"network.password_file = {net.password_file!r}: cannot read ({exc.strerror}); allowed: a readable file"
            ) from None
    return net.password


def _check_file(key: str, path: str) -> str:
    if path and not Path(path).is_file():
        raise ConfigError(f"network.{key} = {path!r}: no such file; allowed: a readable PEM file")
    return path


def zenoh_config(
    net: NetworkConfig,
    *,
    mode: str | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> zenoh.Config:
    """Build a :class:`zenoh.Config` from the ``[network]`` section.

    Each role reads only its own settings, so one profile serves all three: a router
    reads ``listen``, its TLS server certificate, ``credentials_file`` and the ACL
    lists and ignores the client login (``user``, ``password``, ``password_file``); a
    client or peer reads ``connect``, its TLS certificate and the login and ignores
    ``credentials_file``, ``publishers_allowed`` and ``followers_allowed``.
    (``message_key_file`` is read by :func:`bipedtele.auth.load_message_auth`, never here.)

    Parameters
    ----------
    net : NetworkConfig
        The section.
    mode, listen, connect : optional
        Override the section's mode and endpoints (e.g. from command-line flags).

    Raises
    ------
    ConfigError
        Unreadable password/credentials/PEM files of this role.
    """
    mode = mode or net.mode
    router = mode == "router"
    listen = list(net.listen if listen is None else listen)
    connect = list(net.connect if connect is None else connect)
    conf = zenoh.Config()

    def put(key: str, value: Any) -> None:
        conf.insert_json5(key, json.dumps(value))

    put("mode", mode)
    if router:
        listen = router_listen_endpoints(listen, net.links)
    put("connect/endpoints", client_endpoints(connect, net.links) if mode == "client" else connect)
    put("transport/unicast/max_links", MAX_LINKS)
    # Zenoh reassembles a fragmented message before anyone sees it: bound what one message
    # may cost (the largest valid one is a video frame, MAX_VIDEO_PAYLOAD), 1 GiB by default.
    put("transport/link/rx/max_message_size", MAX_ZENOH_MESSAGE)
    # No shared memory: Zenoh would hand every message over 3 kB (the video frames) to a
    # process on the same machine through /dev/shm, around the network path: around TLS,
    # the link layout, a router's queues and any emulated link (docs/links.md).
    put("transport/shared_memory/enabled", False)
    if listen or mode != "client":
        # Explicit endpoints only; a peer with no listen endpoint listens nowhere rather
        # than on an ephemeral port of every interface.
        put("listen/endpoints", listen)
    put("scouting/multicast/enabled", bool(net.multicast_scouting))
    if not net.multicast_scouting:
        put("scouting/gossip/enabled", mode != "client")
    put("connect/timeout_ms", int(net.timeout_s * 1000))
    put("connect/exit_on_failure", False)
    # Reconnection to a lost router or peer: Zenoh retries with a doubling period up to
    # 4 s by default, so a robot could stay cut off for 4 s after its router is back.
    # Retry at least every second (one small TCP connect attempt per endpoint).
    put("connect/retry", {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2.0})
    tls: dict[str, Any] = {}
    if net.tls_root_ca:
        tls["root_ca_certificate"] = _check_file("tls_root_ca", net.tls_root_ca)
    if net.tls_cert:
        cert = _check_file("tls_cert", net.tls_cert)
        key = _check_file("tls_key", net.tls_key)
        tls.update(connect_certificate=cert, connect_private_key=key)
        if mode != "client":  # a client never listens: its certificate is a client one
            tls.update(listen_certificate=cert, listen_private_key=key)
    if net.tls_mutual:
        if not net.tls_cert:
            raise ConfigError(
                "network.tls_mutual = true: needs tls_cert and tls_key; allowed: set them or tls_mutual = false"
            )
        tls["enable_mtls"] = True
    for k, v in tls.items():
        put(f"transport/link/tls/{k}", v)
    if not router:
        password = _read_password(net)
        if net.user or password:
            if not (net.user and password):
                raise ConfigError(
                    "network.user/password: allowed: both a user and a password (or password_file), or neither"
                )
            put("transport/auth/usrpwd/user", net.user)
            put("transport/auth/usrpwd/password", password)
    else:
        if net.credentials_file:
            credential_users(net.credentials_file)
            put("transport/auth/usrpwd/dictionary_file", net.credentials_file)
        acl = access_control_json(net)
        if acl is not None:
            put("access_control", acl)
    return conf


def _zenoh_reason(exc: BaseException) -> str:
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return re.sub(r"\s+at \S+\.rs:\d+\.?$", "", first)  # Zenoh's Rust source location


def _preflight(net: NetworkConfig, connect: list[str]) -> tuple[float, set[str]]:
    """Check a client's endpoints before Zenoh does.

    Returns
    -------
    rtt_s : float
        The longest round trip seen [s].
    checked : set of str
        The protocols (``tcp``, ``tls``) of the endpoints that passed a check.

    Raises
    ------
    LinkError
        When no endpoint passes: which failure each one had.
    """
    cert, key = (net.tls_cert, net.tls_key) if net.tls_mutual else ("", "")
    step = min(STEP_TIMEOUT_S, net.timeout_s)
    # a router that is starting refuses connections for a moment: retry those (only)
    retry_until = time.monotonic() + min(REFUSED_RETRY_S, net.timeout_s)
    while True:
        checks = [check_endpoint(ep, root_ca=net.tls_root_ca, cert=cert, key=key, timeout_s=step) for ep in connect]
        passed = [c for c in checks if c.ok]
        if passed or any(c.kind != "refused" for c in checks) or time.monotonic() + 0.25 > retry_until:
            break
        time.sleep(0.25)
    if not passed:
        first = checks[0].kind
        kind = first if all(c.kind == first for c in checks) else "unreachable"
        raise LinkError(kind, "; ".join(f"{c.endpoint}: {c.detail}" for c in checks))
    checked = {c.endpoint.partition("/")[0] for c in passed} & {"tcp", "tls"}
    return max(c.rtt_s for c in passed), checked


def _open_timeout_s(net: NetworkConfig, rtt_s: float, checked: set[str]) -> float:
    """How long Zenoh may take to open a client session whose links were checked [s].

    A Zenoh session needs about 4 round trips after TCP (TLS, then its own handshake);
    a router that has not accepted it after OPEN_RTTS round trips (at least OPEN_MIN_S)
    refused the login. Without TLS and without a login there is nothing to refuse (and
    a relay such as the delay proxy hides the round trip from the TCP check): the
    profile's ``timeout_s`` then applies unchanged.
    """
    if "tls" not in checked and not net.user:
        return net.timeout_s
    return min(net.timeout_s, max(OPEN_MIN_S, OPEN_RTTS * rtt_s))


def _refusal(net: NetworkConfig, checked: set[str], spent_s: float, zenoh_reason: str) -> LinkError:
    """Return the LinkError of a client whose endpoint checks passed but whose session did not open.

    Zenoh does not tell a client why its router closed a handshake, so the message says
    what was seen (TCP, TLS accepted; no session after the tries) and names both causes
    that fit: a refused login, which the router logs, or a path too slow or lossy for the
    handshake.
    """
    within = f"no session after {OPEN_TRIES} tries in {spent_s:.1f} s"
    if not checked:  # udp, quic, ws...: not checked beforehand
        return LinkError(
            "open",
            f"cannot open the Zenoh session: {zenoh_reason} (no router answered within {spent_s:.1f} s, "
            "or it refused this client's certificate or user/password)",
        )
    if "tls" in checked:
        seen = "TCP and TLS were accepted"
    else:
        seen = "TCP was accepted, by the router or by a relay in front of it"
    slow = "or the router did not answer the handshake in time (a lossy or slow path; the router logs every refusal)"
    if net.links == "split":
        slow += (
            ', or UDP to the router\'s port is blocked (the control link of links = "split"; '
            'where only TCP passes, set network.links = "split-tcp")'
        )
    if net.user:
        return LinkError(
            "credentials",
            f"the router did not open a session ({seen}; {within}): user/password refused for user {net.user!r}, "
            f"{slow}; check network.user and network.password_file against the router's credentials_file",
        )
    return LinkError(
        "credentials",
        f"the router did not open a session ({seen}; {within}): it may require a user/password "
        "(network.user, network.password_file)"
        + ("" if "tls" in checked else " or TLS (a tls/ endpoint)")
        + f", {slow}",
    )


def _open_client(net: NetworkConfig, connect: list[str], conf: zenoh.Config) -> zenoh.Session:
    """Open a client session: endpoint checks, then up to OPEN_TRIES handshakes, each given twice as long.

    A handshake over a lossy or slow path can outlast the first try's few round trips (with
    ``links = "split"`` three links must all open, and a lost TCP SYN alone costs a second):
    the next try doubles the time (within the profile's ``timeout_s`` in all).
    """
    rtt, checked = _preflight(net, connect)
    timeout = _open_timeout_s(net, rtt, checked)
    spent, first = 0.0, ""
    for attempt in range(OPEN_TRIES):
        budget = min(timeout * 2**attempt, net.timeout_s - spent)
        if budget <= 0.05:
            break
        conf.insert_json5("connect/timeout_ms", json.dumps(int(budget * 1000)))
        t0 = time.monotonic()
        try:
            return zenoh.open(conf)
        except zenoh.ZError as exc:
            spent += time.monotonic() - t0
            first = _zenoh_reason(exc)
            if "Unable to connect" not in first:
                raise ConfigError(f"network: cannot open the Zenoh session: {first}") from None
            LOG.debug("no session with the router within %.1f s (try %d of %d)", budget, attempt + 1, OPEN_TRIES)
    raise _refusal(net, checked, spent, first)


@contextmanager
def open_session(
    net: NetworkConfig,
    *,
    mode: str | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> Iterator[zenoh.Session]:
    """Open a Zenoh session from the ``[network]`` section; close it on exit.

    Parameters are as in :func:`zenoh_config`. A client first checks its endpoints
    (:mod:`bipedtele.linkcheck`: name, TCP, TLS) so that a refusal says which one it is,
    then gives Zenoh a few round trips to open the session: when the links were fine
    and Zenoh still fails, the router refused the session (user/password).

    Raises
    ------
    ConfigError
        Bad files or settings, or Zenoh refused the configuration (e.g. a listen
        endpoint cannot be bound).
    LinkError
        A client cannot reach or is refused by its router: one line saying which.
    """
    mode = mode or net.mode
    connect = list(net.connect if connect is None else connect)
    conf = zenoh_config(net, mode=mode, listen=listen, connect=connect)
    client = mode == "client" and bool(connect)
    if not client:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            raise ConfigError(f"network: cannot open the Zenoh session: {_zenoh_reason(exc)}") from None
    else:
        session = _open_client(net, connect, conf)
    LOG.debug("zenoh session %s open (mode %s)", session.zid(), mode)
    try:
        yield session
    finally:
        session.close()


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
    :class:`~bipedtele.auth.MessageAuth`, every message is signed (HMAC-SHA256 over the
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

        With a ``session`` (:class:`~bipedtele.session.Handshake`) the message is MAC'd with
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
    :mod:`bipedtele.linklayout`). On a single link they travel as before.
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
        :func:`bipedtele.auth.load_message_auth`).
    handshake : Handshake, optional
        Commands and feedback are MAC'd with its session key instead, and not sent while
        it has none (:mod:`bipedtele.session`).
    """

    _CONTROL = ("cmd", "feedback", "clock")
    _SESSION = ("cmd", "feedback")

    def __init__(
        self, session: zenoh.Session, keys: Keys, auth: MessageAuth | None = None, handshake: Handshake | None = None
    ) -> None:
        self._session = session
        self.keys = keys
        self.auth = auth
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
                    pub = declare_video_publisher(self._session, key, self.auth)
                elif name == "status":
                    pub = declare_status_publisher(self._session, key, self.auth)
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


# --------------------------------------------------------------------------- receiving


class Received(msgspec.Struct, Generic[M], frozen=True, gc=False):
    """A valid message and its local receive time.

    Attributes
    ----------
    msg : Message
        The decoded message.
    t_recv : float
        Local receive time (``time.time()`` by default) [s].
    nbytes : int
        Size of the payload as it arrived (MAC included) [bytes].
    """

    msg: M
    t_recv: float
    nbytes: int = 0


#: Largest payload [bytes] a receiver reads of a control message (command, feedback,
#: clock, status; a status with every counter and its text is under 4 kB) and of a video
#: frame (the JPEG bound plus its envelope). Anything larger is dropped (``too_large``)
#: before it is copied, authenticated or decoded.
MAX_CONTROL_PAYLOAD = 16 * 1024
MAX_VIDEO_PAYLOAD = MAX_JPEG_BYTES + 4 * 1024
#: Largest message Zenoh reassembles [bytes] (its defragmentation buffer; Zenoh drops larger).
MAX_ZENOH_MESSAGE = MAX_VIDEO_PAYLOAD + 64 * 1024


def _const(value: float, _t: float) -> float:
    return value


class _Receiver(Generic[M]):
    """Shared authentication/decoding/validation/gating for the receivers."""

    def __init__(
        self,
        session: zenoh.Session,
        key: str,
        expect: type[M] | tuple[type[M], ...],
        drops: DropCounter,
        gate: SequenceGate | None = None,
        *,
        estimator: DelayEstimator | None = None,
        clock_sync: ClockSync | None = None,
        clock: Callable[[], float] = time.time,
        ignore_sid: int | None = None,
        on_message: Callable[[Received[M]], None] | None = None,
        auth: MessageAuth | None = None,
        max_future_s: float | None = None,
        max_age_s: float | Callable[[float], float] | None = None,
        on_too_old: Callable[[Received[M]], None] | None = None,
        handshake: Handshake | None = None,
    ) -> None:
        if max_future_s is not None and not max_future_s > 0:
            raise ValueError(f"max_future_s = {max_future_s!r}: allowed: None or a number > 0 s")
        if max_age_s is not None and not callable(max_age_s) and not max_age_s > 0:
            raise ValueError(f"max_age_s = {max_age_s!r}: allowed: None, a number > 0 s or a callable")
        self.key = key
        self._on_message = on_message
        self._expect: tuple[type[M], ...] = expect if isinstance(expect, tuple) else (expect,)
        # one expected class: decode() refuses the others itself; several: checked after
        self._decode_as: type[M] | None = self._expect[0] if len(self._expect) == 1 else None
        self.max_bytes = MAX_VIDEO_PAYLOAD if VideoFrame in self._expect else MAX_CONTROL_PAYLOAD
        self.drops = drops
        self.gate = gate
        self.estimator = estimator
        self.clock_sync = clock_sync
        self.auth = auth
        self.handshake = handshake
        self.max_future_s = max_future_s
        self._max_age: Callable[[float], float] | None = (
            None
            if max_age_s is None
            else max_age_s
            if callable(max_age_s)
            else functools.partial(_const, float(max_age_s))
        )
        self._on_too_old = on_too_old
        # the key expression the sender signed: ours when exact, else the sample's
        self._mac_topic = None if any(c in key for c in "*$") else key
        self._clock = clock
        self._ignore_sid = ignore_sid
        self._lock = threading.Lock()
        self.count = 0
        self._closed = False
        self._sub = session.declare_subscriber(key, self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        # Runs once per message in Zenoh's callback thread, from cold caches: each check
        # below is kept, with as few Python calls as the checks allow.
        t_recv = self._clock()
        drops = self.drops
        try:
            zbytes = sample.payload
            nbytes = len(zbytes)
            if nbytes > self.max_bytes:  # before the copy, the MAC and the decoder
                drops.drop("too_large", f"{self.key}: {nbytes} bytes (at most {self.max_bytes})")
                return
            payload = zbytes.to_bytes()
            skey = None
            if self.handshake is not None:
                try:
                    payload, skey = self.handshake.open(payload, self._mac_topic or str(sample.key_expr))
                except MacError as exc:
                    drops.drop(exc.reason, f"{self.key}: {exc.detail}")
                    return
            elif self.auth is not None:
                try:
                    payload = self.auth.verify(payload, self._mac_topic or str(sample.key_expr))
                except MacError as exc:
                    drops.drop(exc.reason, f"{self.key}: {exc.detail}")
                    return
            elif is_signed(payload):  # not for the decoder: name the missing key, not msgpack
                drops.drop("mac_unexpected", f"{self.key}: {UNEXPECTED_MAC_LINE}")
                return
            try:
                got = decode(payload, self._decode_as)
            except MessageError as exc:
                drops.drop(exc.reason, exc.detail)
                return
            if self._decode_as is None and not isinstance(got, self._expect):
                drops.drop("unknown_kind", f"k={got.KIND!r}")
                return
            msg = cast(M, got)  # one of the expected kinds: decode() checked it, or the line above
            if msg.sid == self._ignore_sid:
                return  # our own message on a shared key (clock, status)
            t_sent = msg.t
            sync = self.clock_sync
            if sync is not None:
                if not sync.ready:
                    drops.drop("clock_not_synced", f"{self.key}: the peer's clock offset is not known yet")
                    return
                t_sent = sync.to_local(t_sent)
            if self.max_future_s is not None and t_sent - t_recv > self.max_future_s:
                drops.drop("future", f"{self.key}: sid={msg.sid} seq={msg.seq} stamped {t_sent - t_recv:.3f} s ahead")
                return
            max_age = self._max_age
            if max_age is not None and t_recv - t_sent > max_age(t_recv):
                # before the gate and the delay estimator: an old message (a replay, a
                # queue's backlog) never binds the gate nor moves the delay estimate
                if self._on_too_old is not None:
                    self._on_too_old(Received(msg, t_recv, nbytes))
                else:
                    drops.drop("too_old", f"{self.key}: sid={msg.sid} seq={msg.seq} sent {t_recv - t_sent:.3f} s ago")
                return
            if self.gate is not None:
                reason = self.gate.accept(msg)
                if reason is not None:
                    drops.drop(reason, f"sid={msg.sid} seq={msg.seq}")
                    return
            if skey is not None and self.handshake is not None:
                self.handshake.accepted(skey, msg.sid)  # authenticated, fresh, gated: the session is live
            if self.estimator is not None:
                # a delay is never negative: a message seemingly received before it was
                # sent (clock offset error, rounding) counts as delay 0
                self.estimator.update(t_sent if t_sent < t_recv else t_recv, t_recv)
            rec = Received(msg, t_recv, nbytes)
            self._deliver(rec)
            if self._on_message is not None:
                self._on_message(rec)
        except Exception as exc:  # never let a bad sample kill Zenoh's callback thread
            drops.drop("receiver_error", f"{type(exc).__name__}: {exc}")

    def _deliver(self, rec: Received[M]) -> None:
        raise NotImplementedError

    def close(self) -> None:
        """Undeclare the subscriber (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        self._sub.undeclare()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class LatestReceiver(_Receiver[M]):
    """Keeps only the newest valid message of one key (a ring of one).

    Parameters
    ----------
    session : zenoh.Session
    key : str
        Key expression to subscribe to.
    expect : type or tuple of types
        Accepted message class(es); any other kind is dropped (``unknown_kind``).
    drops : DropCounter
        Where invalid/stale messages are counted.
    gate : SequenceGate, optional
        Drops stale and duplicated messages.
    estimator : DelayEstimator, optional
        Fed with every accepted message (send time, receive time) at reception, so the
        delay estimate sees every message, not only those the loop takes.
    clock_sync : ClockSync, optional
        ntp mode: converts the sender's send time to the local clock first; until it
        is ready (no clock answer yet, so the peer's clock may differ by anything) every
        message is dropped as ``clock_not_synced``. Never give it to the receiver of
        the clock answers themselves.
    clock : callable
        Local receive-time source [s] (``time.time``).
    ignore_sid : int, optional
        Messages with this sid (our own, on a shared key) are ignored silently.
    on_message : callable, optional
        Called with each accepted :class:`Received` in Zenoh's callback thread (keep
        it short: answer a ping, wake a loop). Exceptions are counted as
        ``receiver_error`` drops.
    auth : MessageAuth, optional
        Every payload must carry a valid tag: unsigned ones are dropped as ``no_mac``,
        wrong tags as ``bad_mac``, before anything is decoded.
    handshake : Handshake, optional
        Instead of ``auth``: every payload must carry a tag under a session key this side
        holds (:meth:`~bipedtele.session.Handshake.open`; else ``old_session``, or
        ``no_session`` for one under the master key); a message that passes every check
        (the gate included) marks its session live (and binds a follower to it).
    max_future_s : float, optional
        A message whose send time (on the local clock, after ``clock_sync``) is more
        than this ahead of its receive time [s] is dropped as ``future``
        (``[clock] max_future_s``). None: no check.
    max_age_s : float or callable, optional
        A message sent longer ago than this [s] (receive time minus send time on the
        local clock; a callable is given the receive time and returns the bound) is
        dropped as ``too_old`` before the gate and the delay estimator see it, so a
        replay of old traffic never binds the gate. None: no check.
    on_too_old : callable, optional
        Called with a message refused as too old instead of counting the drop (the
        caller counts it, e.g. the leader's ``fb_too_old``).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._latest: Received[M] | None = None
        self._fresh = False
        super().__init__(*args, **kwargs)

    def _deliver(self, rec: Received[M]) -> None:
        with self._lock:
            self._latest = rec
            self._fresh = True
            self.count += 1

    def latest(self) -> Received[M] | None:
        """Return the newest valid message (kept; None before the first)."""
        with self._lock:
            return self._latest

    def take(self) -> Received[M] | None:
        """Return the newest valid message if it was not taken before, else None."""
        with self._lock:
            if not self._fresh:
                return None
            self._fresh = False
            return self._latest


class MessageReceiver(_Receiver[M]):
    """Queue of every valid message of one key (bounded; overflow is counted).

    Same parameters as :class:`LatestReceiver`, plus ``maxlen`` (queue bound). When the
    queue is full the oldest message is dropped and counted as ``overflow``.
    """

    def __init__(self, *args: Any, maxlen: int = 1024, **kwargs: Any) -> None:
        self._q: deque[Received[M]] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition(threading.Lock())
        super().__init__(*args, **kwargs)

    def _deliver(self, rec: Received[M]) -> None:
        overflow = False
        with self._cond:
            if len(self._q) >= self._maxlen:
                self._q.popleft()
                overflow = True
            self._q.append(rec)
            self.count += 1
            self._cond.notify_all()
        if overflow:
            self.drops.drop("overflow", self.key)

    def get(self, timeout: float | None = None) -> Received[M] | None:
        """Return the oldest queued message, or None.

        ``timeout`` [s]: None or 0 does not wait; a positive value waits at most that long.
        """
        with self._cond:
            if not self._q and timeout:
                self._cond.wait_for(lambda: bool(self._q), timeout)
            return self._q.popleft() if self._q else None

    def drain(self) -> list[Received[M]]:
        """Every queued message, oldest first."""
        with self._cond:
            out = list(self._q)
            self._q.clear()
            return out

    def __len__(self) -> int:
        with self._cond:
            return len(self._q)


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
