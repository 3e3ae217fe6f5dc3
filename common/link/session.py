r"""The session handshake (message key only): per-session keys that earlier sessions cannot replay.

With ``[network] message_key_file`` set, leader and follower bind with a handshake of
:class:`~bipedtele.link.messages.Hello` messages (sealed with the shared *master* key, sent on
the clock key), and Commands and Feedback are then sealed (AES-256-GCM,
:mod:`bipedtele.link.auth`) with a *session key*::

    K = HKDF-SHA256(master, salt = nonce_leader | nonce_follower,
                    info = b"bipedtele session v1" | sid_leader | sid_follower)   (4 bytes each, big-endian)

Nonces are 32 random bytes, fresh for each pairing: the leader draws one at start and a
new one whenever it gives up its bound follower session; the follower draws one for each
leader session (``sid``, ``nonce``) it answers. So a session key is never derived twice,
and traffic MAC'd with an earlier session's key fails authentication whatever the clocks
say (dropped as ``old_session``).

The exchange (one round trip before the first command)::

    leader   Hello(nonce=nL, peer=0)                       4 Hz until bound, then 1 Hz
    follower Hello(nonce=nF, peer_sid=sidL, peer_nonce=nL)  the answer (nF fresh for (sidL, nL))
    leader   binds: the answer echoes its *current* nonce; K known, commands go out under K
    follower binds to that leader session when its sequence gate accepts a command under K
             (a new session takes over only after the bound one's silence: the watchdog rule)

A replayed Hello echoes an old nonce and completes nothing; a replayed leader Hello gets
an answer with a fresh follower nonce, whose key the replayer cannot compute. The leader
binds to one follower session (the first that echoes its nonce) and leaves it only after
``takeover_after_s`` of silence when another echoes (then with a new nonce and a new
handshake). A side with no session sends nothing on cmd/feedback (the robot stands).

Status and Video travel under a watch key per session (:class:`bipedtele.link.auth.WatchAuth`:
derived from the robot's watch key and the sender's random *watch epoch*, so an observer
holding the robot's watch key can read them) and the clock pings under the master key
(docs/network.md). Each Hello announces its sender's watch epoch; the leader opens video
only under the epoch of the follower session this handshake bound. A replay of an earlier
session's video or status is refused by that (``old_session``), by the receivers' age bound
and, for what the leader shows as live, by :class:`PeerBound`: only the follower session
this handshake bound (a fresh nonce of its own) is shown.
"""

from __future__ import annotations

import os
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any, Final

from bipedtele.link.auth import (
    MAC_MAGIC,
    MAC_OVERHEAD,
    SESSION_MAGIC,
    MacError,
    MessageAuth,
)
from bipedtele.link.messages import NONCE_BYTES, ZERO_EPOCH, ZERO_NONCE, Hello

__all__ = [
    "INFO",
    "LIVE_MAX_AGE_S",
    "OLD_SESSION_LINE",
    "Handshake",
    "PeerBound",
    "SessionKey",
    "live_checks",
    "session_info",
]

INFO: Final = b"bipedtele session v1"
#: What a payload under a session key this side does not hold is.
OLD_SESSION_LINE: Final = "signed with a session key this side does not hold (an earlier session's traffic replayed, or another peer's session)"
#: Hello rates [Hz]: until the handshake completes, then to let a restarted peer rebind.
FAST_HZ: Final = 4.0
SLOW_HZ: Final = 1.0
#: Fewest seconds between two answers to the peer's Hellos (replayed Hellos cost at most this rate).
ANSWER_GAP_S: Final = 0.02
#: Leader sessions the follower keeps answered keys for (beyond the bound one).
MAX_CANDIDATES: Final = 4
#: A leader takes the bound follower's traffic it cannot verify for another leader session's
#: (``other_leader``, not ``bad_mac``) while the follower's Hellos named another leader
#: session this recently [s] (they come at SLOW_HZ while it is bound).
ELSEWHERE_S: Final = 3.0
#: Age bound of video and status [s]: older ones (a replay, a backlog) are never taken as live.
LIVE_MAX_AGE_S: Final = 3.0
#: The line of ``other_leader``.
OTHER_LEADER_LINE: Final = (
    "the robot's traffic to another leader session (the robot follows another operator: "
    "see who holds it, docs/fleet.md, Hand-over)"
)


def session_info(sid_leader: int, sid_follower: int) -> bytes:
    """Return HKDF's ``info`` of a leader and a follower session."""
    return INFO + sid_leader.to_bytes(4, "big") + sid_follower.to_bytes(4, "big")


class SessionKey:
    """One pairing: the peer's session and nonce, our nonce, the derived key.

    Attributes
    ----------
    peer_sid : int
    peer_nonce, nonce : bytes
    auth : MessageAuth
        The session key (frames with ``SESSION_MAGIC``).
    t_heard : float
        Monotonic time of the last message accepted under this key [s].
    confirmed : bool
        The peer showed it holds the key (an echo of our nonce, or a message under the key).
    peer_watch : bytes
        The peer's watch epoch, as its Hello announced it (zeros: none).
    """

    __slots__ = ("auth", "confirmed", "nonce", "peer_nonce", "peer_sid", "peer_watch", "t_heard")

    def __init__(self, auth: MessageAuth, peer_sid: int, peer_nonce: bytes, nonce: bytes, now: float) -> None:
        self.auth = auth
        self.peer_sid = peer_sid
        self.peer_nonce = peer_nonce
        self.nonce = nonce
        self.t_heard = now
        self.confirmed = False
        self.peer_watch = ZERO_EPOCH

    @property
    def peer(self) -> tuple[int, bytes]:
        """``(peer_sid, peer_nonce)``: the peer session this key pairs with."""
        return self.peer_sid, self.peer_nonce


class Handshake:
    """The handshake state machine of one process (see the module docstring).

    Parameters
    ----------
    role : str
        ``leader`` or ``follower``.
    sid : int
        This process's session id.
    master : MessageAuth
        The shared key (``[network] message_key_file``).
    takeover_after_s : float
        Leader: silence of the bound follower session after which another that echoes our
        nonce may take over [s]. (The follower's rule is its command gate's.)
    clock : callable
        Monotonic time [s] (injectable).
    wall : callable
        Send-time source for the Hellos [s].
    rand : callable
        ``rand(n)``: n random bytes (``os.urandom``).
    watch_epoch : bytes
        This process's watch epoch (:class:`bipedtele.link.auth.WatchAuth`), announced in its
        Hellos; zeros: none.

    Notes
    -----
    Thread-safe: Zenoh's callbacks (Hellos in, verification), the Hello sender and the
    loops' publishers share it under one lock.
    """

    def __init__(
        self,
        role: str,
        sid: int,
        master: MessageAuth,
        *,
        takeover_after_s: float = 0.5,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        rand: Callable[[int], bytes] = os.urandom,
        watch_epoch: bytes = ZERO_EPOCH,
    ) -> None:
        if role not in ("leader", "follower"):
            raise ValueError(f"role = {role!r}: allowed: leader, follower")
        self.role = role
        self.peer_role = "follower" if role == "leader" else "leader"
        self.sid = int(sid)
        self._master = master
        self.takeover_after_s = float(takeover_after_s)
        self._clock, self._wall, self._rand = clock, wall, rand
        self.watch_epoch = bytes(watch_epoch)
        self._lock = threading.Lock()
        self._seq = 0
        self._nonce = self._fresh()  # the leader's current nonce; the follower's unsolicited Hellos'
        self._current: SessionKey | None = None
        self._candidates: OrderedDict[tuple[int, bytes], SessionKey] = OrderedDict()  # follower only
        self._answers: OrderedDict[tuple[int, bytes], None] = OrderedDict()  # peers owed an answer
        self._next_hello = -float("inf")
        self._last_answer = -float("inf")
        self._elsewhere_t = -float("inf")  # leader: when the bound follower last named another leader session
        self.completed = 0  # handshakes completed (bindings)
        self.changed = threading.Event()  # set when a Hello should go out now

    def _fresh(self) -> bytes:
        nonce = self._rand(NONCE_BYTES)
        if len(nonce) != NONCE_BYTES or nonce == ZERO_NONCE:
            raise ValueError("rand: allowed: a source of random bytes")
        return nonce

    # ------------------------------------------------------------------ state

    @property
    def complete(self) -> bool:
        """True while a session key is in use (this side sends under it)."""
        with self._lock:
            return self._current is not None

    @property
    def peer_sid(self) -> int | None:
        """The peer session bound now (None: none)."""
        with self._lock:
            return None if self._current is None else self._current.peer_sid

    @property
    def peer_watch_epoch(self) -> bytes | None:
        """The bound peer's watch epoch (None: no peer bound, or it announced none)."""
        with self._lock:
            cur = self._current
            return None if cur is None or cur.peer_watch == ZERO_EPOCH else cur.peer_watch

    @property
    def nonce(self) -> bytes:
        """The leader's current nonce (the follower's: that of its bound session, else of its unsolicited Hellos)."""
        with self._lock:
            cur = self._current
            return cur.nonce if cur is not None and self.role == "follower" else self._nonce

    def _derive(self, peer_sid: int, peer_nonce: bytes, nonce: bytes, now: float) -> SessionKey:
        if self.role == "leader":
            salt, info = nonce + peer_nonce, session_info(self.sid, peer_sid)
        else:
            salt, info = peer_nonce + nonce, session_info(peer_sid, self.sid)
        return SessionKey(self._master.derive(salt, info), peer_sid, peer_nonce, nonce, now)

    # ------------------------------------------------------------------ Hellos

    def _hello(self, nonce: bytes, peer_sid: int, peer_nonce: bytes) -> Hello:
        self._seq += 1
        return Hello(
            sid=self.sid,
            seq=self._seq,
            t=self._wall(),
            role=self.role,
            nonce=nonce,
            peer_sid=peer_sid,
            peer_nonce=peer_nonce,
            watch=self.watch_epoch,
        )

    def _own_hello(self) -> Hello:
        cur = self._current
        if cur is None:
            return self._hello(self._nonce, 0, ZERO_NONCE)
        return self._hello(cur.nonce, cur.peer_sid, cur.peer_nonce)

    def due(self) -> list[Hello]:
        """Return the Hellos to send now: answers owed, and ours when its period is up."""
        now = self._clock()
        out: list[Hello] = []
        with self._lock:
            self.changed.clear()
            if self._answers and now - self._last_answer >= ANSWER_GAP_S:
                self._last_answer = now
                for peer in self._answers:
                    s = self._current if self._current is not None and self._current.peer == peer else None
                    s = s or self._candidates.get(peer)
                    if s is not None:
                        out.append(self._hello(s.nonce, s.peer_sid, s.peer_nonce))
                    elif self.role == "leader":
                        out.append(self._own_hello())
                self._answers.clear()
            period = 1.0 / (SLOW_HZ if self._current is not None else FAST_HZ)
            if out:
                self._next_hello = now + period  # an answer just went out: it is our Hello too
            elif now >= self._next_hello:
                self._next_hello = now + period
                out.append(self._own_hello())
        # leader: one own Hello is enough (several answers owed are the same Hello)
        return out[:1] if self.role == "leader" else out

    def _owe(self, peer: tuple[int, bytes]) -> None:
        self._answers[peer] = None
        while len(self._answers) > MAX_CANDIDATES + 1:
            self._answers.popitem(last=False)
        self.changed.set()

    def on_hello(self, h: Hello) -> None:
        """Take one Hello that verified with the master key (Zenoh's thread)."""
        if h.role != self.peer_role or h.sid == self.sid:
            return
        now = self._clock()
        with self._lock:
            if self.role == "leader":
                self._leader_hello(h, now)
            else:
                self._follower_hello(h, now)

    def _leader_hello(self, h: Hello, now: float) -> None:
        cur = self._current
        if cur is not None and h.sid == cur.peer_sid and h.peer_sid not in (0, self.sid):
            self._elsewhere_t = now  # our follower is bound to another leader session
        if h.peer_sid != self.sid or h.peer_nonce != self._nonce:
            self._owe((h.sid, h.nonce))  # not an answer to our current nonce: send it ours
            return
        cur = self._current
        if cur is None:
            s = self._derive(h.sid, h.nonce, self._nonce, now)
            s.confirmed = True
            s.peer_watch = h.watch  # authenticated (master key) and an answer to our nonce
            self._current = s
            self.completed += 1
            self._next_hello = now  # tell the follower at once that we hold its nonce
            self.changed.set()
        elif cur.peer == (h.sid, h.nonce):
            return
        elif now - cur.t_heard > self.takeover_after_s:
            # another follower session answers while ours is silent: a new nonce, a new handshake
            self._current = None
            self._nonce = self._fresh()
            self._next_hello = now
            self.changed.set()
        # else: ours is live, the other gets nothing

    def _follower_hello(self, h: Hello, now: float) -> None:
        peer = (h.sid, h.nonce)
        cur = self._current
        if cur is not None and cur.peer == peer:
            s = cur
        else:
            got = self._candidates.get(peer)
            if got is None:
                got = self._derive(h.sid, h.nonce, self._fresh(), now)
                self._candidates[peer] = got
                # evict the oldest unconfirmed first (replayed Hellos never confirm)
                while len(self._candidates) > MAX_CANDIDATES:
                    old = next((k for k, v in self._candidates.items() if not v.confirmed), None)
                    self._candidates.pop(old if old is not None else next(iter(self._candidates)))
            else:
                self._candidates.move_to_end(peer)
            s = got
        if h.peer_sid == self.sid and h.peer_nonce == s.nonce:
            s.confirmed = True  # the leader holds our nonce for it
        else:
            self._owe(peer)

    # ------------------------------------------------------------------ session crypto

    def sign(self, body: bytes, topic: str) -> bytes | None:
        """Return ``body`` framed under the session key, or None with no session (not sent)."""
        cur = self._current
        return None if cur is None else cur.auth.sign(body, topic)

    def open(self, payload: bytes, topic: str) -> tuple[bytes, SessionKey]:
        """Return the body of a session-sealed payload and the session it opened under.

        The payload's key id picks the key: the bound session's, or (follower) one of
        the leader sessions answered.

        Raises
        ------
        MacError
            ``no_session`` (sealed with the message key, not a session key), ``no_mac``
            (not sealed), ``bad_mac`` (under a key this side holds, but it does not open:
            altered), ``other_leader`` (leader: a session key it does not hold while the
            bound follower names another leader session) or ``old_session`` (under a
            session key this side does not hold: an earlier session's or another pair's).
        """
        if payload[:4] != SESSION_MAGIC or len(payload) < MAC_OVERHEAD:
            if payload[:4] == MAC_MAGIC:
                raise MacError(
                    "no_session",
                    f"signed with the message key, not a session key ({topic}): a peer without the handshake?",
                )
            self._master.verify(payload, topic)  # raises no_mac with its line
            raise MacError("no_session", topic)  # pragma: no cover - verify raised
        with self._lock:
            keys = ([self._current] if self._current is not None else []) + list(reversed(self._candidates.values()))
        for s in keys:
            if s.auth.holds(payload):
                return s.auth.open_framed(payload, topic), s  # bad_mac if it does not open
        # Sealed, the plaintext hidden: a session key this side does not hold. The leader
        # whose follower lately named another leader session: the robot's traffic to it.
        if self.role == "leader" and keys and self._clock() - self._elsewhere_t < ELSEWHERE_S:
            raise MacError("other_leader", f"{OTHER_LEADER_LINE} ({topic})")
        raise MacError("old_session", f"{OLD_SESSION_LINE} ({topic})")

    def answers(self, peer_sid: int) -> bool:
        """Follower: whether ``peer_sid`` is a leader session that completed the handshake.

        Bound or not (a confirmed candidate holds our fresh nonce: live, not a replay).
        The clock link answers such a session's pings too, so a leader waiting for the
        robot (held by another operator) syncs its clock and reads the robot's status.
        """
        with self._lock:
            cur = self._current
            if cur is not None and cur.peer_sid == peer_sid:
                return True
            return any(s.confirmed and s.peer_sid == peer_sid for s in self._candidates.values())

    def accepted(self, s: SessionKey, sid: int) -> None:
        """Mark ``s`` live (and bound): a message under it passed every check, the gate included."""
        now = self._clock()
        with self._lock:
            s.t_heard = now
            s.confirmed = True
            if s is self._current or s.peer_sid != sid:
                return
            if self._candidates.get(s.peer) is s:
                # follower: the gate followed this leader session, so the session does too
                del self._candidates[s.peer]
                self._current = s
                self.completed += 1
                self._next_hello = now
                self.changed.set()


class PeerBound:
    """A gate that passes only the messages of the peer session a handshake bound.

    Video (and the follower's status, on the leader) travel under the watch key, not a
    session key: without this an earlier follower session's frames, replayed, could bind
    the leader's video gate and be shown as live. With it, a frame is shown only when its
    ``sid`` is that of the follower session that answered this leader's current nonce.

    Parameters
    ----------
    inner : MessageGate
        The gate behind (sequence, duplicates).
    peer_sid : callable
        The bound peer session, None while none is bound (:attr:`Handshake.peer_sid`).
    strict : bool
        True: nothing passes while no peer is bound (video). False: until a peer is bound,
        the inner gate decides alone (status, which also says why a link fails).
    """

    def __init__(self, inner: Any, peer_sid: Callable[[], int | None], *, strict: bool = True) -> None:
        self.inner = inner
        self._peer_sid = peer_sid
        self.strict = strict

    def accept(self, msg: Any) -> str | None:
        """Return None if ``msg`` is the bound peer's and the inner gate takes it, else the reason."""
        peer = self._peer_sid()
        if peer is None:
            if self.strict:
                return "no_session"
        elif msg.sid != peer:
            return "old_session" if self.strict else "foreign_session"  # status: as the sequence gate says it
        return self.inner.accept(msg)  # type: ignore[no-any-return]

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)  # live_sid and the like, as the inner gate's


def live_checks(node: Any, key: str, gate: Any, max_age_s: Any) -> tuple[Any, Any]:
    """Return the gate and age bound a node's receiver of ``key`` runs with.

    Video and status get :data:`LIVE_MAX_AGE_S` unless the caller gives a bound; with a
    handshake, the leader's video passes only the bound follower session's frames
    (:class:`PeerBound`, strict) and its status the bound follower's once one is bound.
    Other keys are left as given.
    """
    keys, hs = node.keys, node.handshake
    if key not in (keys.video, keys.status):
        return gate, max_age_s
    if max_age_s is None:
        max_age_s = LIVE_MAX_AGE_S
    if hs is not None and gate is not None and node.role == "leader":
        gate = PeerBound(gate, lambda: hs.peer_sid, strict=key == keys.video)
    return gate, max_age_s
