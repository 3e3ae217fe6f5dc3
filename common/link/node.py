"""The node runtime both programs (``bipedtele leader``, ``bipedtele follower``) run on.

A :class:`Node` owns what every node does the same way, so that each program's ``main``
only wires its own parts (a robot and its loop; a device, the cockpit and the haptic
loop):

- the checks before any I/O: message-key file, clock mode, ``--record`` not an existing
  file (a bad one raises :class:`~bipedtele.config.profile.ConfigError`);
- shutdown: SIGINT/SIGTERM set :attr:`Node.stop` (programs loop ``while not
  node.stopping``), and every part entered with :meth:`Node.enter` closes, in reverse
  order, when the ``with node:`` block ends (as in zenoh-python's examples);
- the Zenoh session and the publishers of the robot's keys;
- declarations: presence (:meth:`Node.declare_presence`, :meth:`Node.watch_presence`) and
  receivers (:meth:`Node.receive`) with the node's checks applied (message
  authentication, clock conversion in ntp mode, the future-stamp limit), each accepted
  message recorded once, in the receiver, under its topic;
- clock sync: one :class:`~bipedtele.link.clocklink.ClockLink` (pings answered off the
  loop thread) and its receiver (:meth:`Node.link_clocks`);
- the recorder (:meth:`Node.start_recording`, :meth:`Node.record`) and the drop counter
  every receiver and the node's Status share (:attr:`Node.drops`);
- the loop clock: the wall clock in real time, or a :class:`StepClock` that moves one
  loop period per tick when a simulation runs faster than real time.

The node never imports the leader or follower packages.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar, cast

import zenoh
from bipedtele.config.profile import Config, ConfigError
from bipedtele.config.sections import ClockConfig, NetworkConfig, RecordConfig, RobotConfig
from bipedtele.link.auth import MessageAuth, WatchAuth, load_message_auth
from bipedtele.link.clock import ClockSync
from bipedtele.link.clocklink import ClockLink
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import MessageGate
from bipedtele.link.inbox import LatestInbox
from bipedtele.link.messages import ClockPing, ClockPong, Hello, Message, new_session_id
from bipedtele.link.receivers import LatestReceiver, Received
from bipedtele.link.relink import RELINK_SILENCE_S, RelinkSession, describe_control, relink_control
from bipedtele.link.session import Handshake, live_checks
from bipedtele.link.transport import Keys, MessagePublisher, PresenceWatcher, Publishers, declare_presence
from bipedtele.link.zenohsession import open_raw, open_session
from bipedtele.recording.files import recording_for_run
from bipedtele.recording.foxglovelive import LiveView, parse_address
from bipedtele.recording.recorder import Recorder
from bipedtele.shutdown import shutdown_on_signals

__all__ = ["Node", "StepClock"]

LOG = logging.getLogger(__name__)

M = TypeVar("M", bound=Message)
T = TypeVar("T")


class StepClock:
    """Loop clock of a run faster than real time: ``t0 + ticks * period_s``.

    Message times follow the loop's time, offset to the wall clock at the start so that
    receivers find them plausible.

    Parameters
    ----------
    period_s : float
        Loop period [s].
    t0 : float, optional
        Time of tick 0 [s] (default: the wall clock now).
    """

    def __init__(self, period_s: float, t0: float | None = None) -> None:
        self.period_s = float(period_s)
        self.t0 = time.time() if t0 is None else float(t0)
        self.ticks = 0

    def __call__(self) -> float:
        """Return the loop time [s]."""
        return self.t0 + self.ticks * self.period_s

    def advance(self) -> None:
        """Move on by one loop period."""
        self.ticks += 1


class Node:
    """One process of the teleoperation link (see the module docstring).

    Parameters
    ----------
    cfg : Config
        The loaded profile.
    role : str
        ``leader`` or ``follower`` (presence, recording file prefix, drop counter name).
    record : Path, optional
        The recording file asked for (``--record``); it must not exist. None: a new file
        in ``[record] dir`` when ``[record] enabled``, else no recording.
    sid : int, optional
        This node's session id (default: a new random one).
    takeover_after_s : float
        The peer's silence [s] after which the session handshake binds another peer (the
        leader's feedback timeout, the follower's watchdog: each role passes its own).

    Raises
    ------
    ConfigError
        ``record`` exists, or the message-key file is bad (checked before any I/O).
    """

    def __init__(
        self, cfg: Config, role: str, *, takeover_after_s: float, record: Path | None = None, sid: int | None = None
    ) -> None:
        if record is not None and record.exists():
            raise ConfigError(f"--record {record}: the file exists; allowed: a new file (never overwritten)")
        self.cfg = cfg
        self.role = role
        self.keys = Keys(cfg.get(RobotConfig).id)
        self.sid = new_session_id() if sid is None else int(sid)
        ck = cfg.get(ClockConfig)
        self.ntp: bool = ck.mode == "ntp"
        self.sync: ClockSync | None = ClockSync(ck.ping_window) if self.ntp else None
        self.max_future_s = float(ck.max_future_s)
        self._conservative_split = bool(ck.conservative_split)  # read in round_trip, a tick's call
        self.auth: MessageAuth | None = load_message_auth(cfg.get(NetworkConfig))
        # Video and status under the watch key (an observer holds only that one).
        # (a key of this session's own, :class:`bipedtele.link.auth.WatchAuth`, its epoch in the Hellos)
        self.watch_auth: WatchAuth | None = self.auth.watch() if self.auth is not None else None
        # With the key: the session handshake (commands and feedback under a per-session key).
        # The leader leaves a silent follower session after its feedback timeout; the
        # follower's takeover rule is its command gate's (watchdog).
        self.handshake: Handshake | None = None
        # Video opens only under the bound follower session's watch epoch (leader).
        self.video_auth: WatchAuth | None = self.watch_auth
        if self.auth is not None and self.watch_auth is not None:
            hs = self.handshake = Handshake(
                role, self.sid, self.auth, takeover_after_s=takeover_after_s, watch_epoch=self.watch_auth.epoch
            )
            if role == "leader":
                self.video_auth = self.watch_auth.pinned(lambda: hs.peer_watch_epoch)
        self.drops = DropCounter(role)
        self.recorder: Recorder | None = None
        self._record_path = record
        self._stack = contextlib.ExitStack()
        self._stop: threading.Event | None = None
        self._session: zenoh.Session | None = None
        self._pubs: Publishers | None = None
        self._relink: RelinkSession | None = None
        self._control_next, self._control_words = -float("inf"), "none"
        self._peer: PresenceWatcher | None = None

    # ------------------------------------------------------------------ lifetime

    def __enter__(self) -> Node:
        """Install the signal handlers, open the session and the publishers."""
        with contextlib.ExitStack() as stack:
            self._stop = stack.enter_context(shutdown_on_signals())
            self._session = self._open(stack)
            self._pubs = stack.enter_context(
                Publishers(
                    self._session, self.keys, auth=self.auth, handshake=self.handshake, watch_auth=self.watch_auth
                )
            )
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        """Close every part entered, newest first, then the session."""
        self._stack.close()

    def _open(self, stack: contextlib.ExitStack) -> zenoh.Session:
        """Open the session: one that reopens itself when its control link is lost (split layouts)."""
        net = self.cfg.get(NetworkConfig)
        control = relink_control(net)
        if not control:
            return stack.enter_context(open_session(net))
        self._relink = RelinkSession(
            lambda: open_raw(net),
            control=control,
            silence_s=RELINK_SILENCE_S,
            peer_present=lambda: self._peer is not None and self._peer.alive,
        )
        stack.callback(self._relink.close)
        self.drops.on_live = self._relink.heard  # refused by policy (held robot...): the link carries traffic
        session = cast(zenoh.Session, self._relink)  # the declarations' surface of a session
        peer = "leader" if self.role == "follower" else "follower"
        self._peer = stack.enter_context(PresenceWatcher(session, self.keys, peer))
        LOG.info("control link: %s (network.links = %r)", self._relink.control_now(), net.links)
        return session

    @property
    def control_link(self) -> str:
        """The protocol of the link that carries control now (``udp``, ``tls``...; ``none``: no router)."""
        if self._relink is not None:
            return self._relink.control_now()
        if self._session is None:
            return "none"
        try:
            return describe_control(list(self._session.info.links()))
        except zenoh.ZError:
            return "none"

    def control_words(self, now: float) -> str | None:
        """Return :attr:`control_link` for a status line, looked up at most once a second.

        ``now`` is any clock in seconds; None where the session does not watch a control
        link of its own (not a split layout).
        """
        if self._relink is None:
            return None
        if now >= self._control_next:
            self._control_next = now + 1.0
            self._control_words = self._relink.control_now()
        return self._control_words

    @property
    def reopens(self) -> int:
        """How many times the session was reopened (a lost or silent control link)."""
        return 0 if self._relink is None else self._relink.reopens

    def _heard(self) -> None:
        if self._relink is not None:
            self._relink.heard()

    def enter(self, part: AbstractContextManager[T]) -> T:
        """Enter ``part`` (a robot, a device, a receiver...) for the node's lifetime."""
        return self._stack.enter_context(part)

    def on_close(self, fn: Callable[[], object]) -> None:
        """Call ``fn()`` when the node closes (before the parts entered earlier)."""
        self._stack.callback(fn)

    @property
    def stop(self) -> threading.Event:
        """Set by SIGINT/SIGTERM (or by anyone who wants the node's loop to end)."""
        if self._stop is None:
            raise RuntimeError("Node.stop: enter the node first (with node: ...)")
        return self._stop

    @property
    def stopping(self) -> bool:
        """True once a stop was asked for."""
        return self._stop is not None and self._stop.is_set()

    def run_stepped(self, clock: StepClock, step: Callable[[float], bool]) -> int:
        """Run a loop faster than real time: ``step(t)`` at ``clock``'s time, then the clock moves on.

        The one fast-mode loop of both programs (``--realtime off``): it stops when ``step``
        returns False or a stop is asked for (SIGINT/SIGTERM).

        Parameters
        ----------
        clock : StepClock
            The loop's clock (message times follow it).
        step : callable
            ``step(t) -> bool``: one period at loop time ``t`` [s]; False ends the run.

        Returns
        -------
        int
            Periods run.
        """
        n = 0
        while not self.stopping:
            n += 1
            if not step(clock()):
                break
            clock.advance()
        return n

    @property
    def session(self) -> zenoh.Session:
        """The open Zenoh session."""
        if self._session is None:
            raise RuntimeError("Node.session: enter the node first (with node: ...)")
        return self._session

    @property
    def pubs(self) -> Publishers:
        """The publishers of the robot's keys."""
        if self._pubs is None:
            raise RuntimeError("Node.pubs: enter the node first (with node: ...)")
        return self._pubs

    # ------------------------------------------------------------------ recording

    def start_recording(self, metadata: dict[str, Any], **kwargs: Any) -> Recorder | None:
        """Start the run's recording (see ``record``); None when the run records nothing.

        ``kwargs`` go to :class:`~bipedtele.recording.recorder.Recorder` (e.g. ``jpeg_every``).
        """
        rc = self.cfg.get(RecordConfig)
        live = self._live_view(rc.foxglove) if rc.foxglove else None
        if self._record_path is None and not rc.enabled:
            if live is None:
                return None
            self.recorder = self.enter(Recorder(None, flush_s=rc.flush_s, live=live, **kwargs))  # live only
            return self.recorder
        try:
            self.recorder = self.enter(
                recording_for_run(
                    self._record_path,
                    rc.dir,
                    self.role,
                    flush_s=rc.flush_s,
                    metadata={"role": self.role, "config": self.cfg.to_dict(), **metadata},
                    live=live,
                    **kwargs,
                )
            )
        except BaseException:
            if live is not None:
                live.close()
            raise
        return self.recorder

    def _live_view(self, address: str) -> LiveView:
        """Start the Foxglove live view (``[record] foxglove``, ``--foxglove``)."""
        host, port = parse_address(address)
        try:
            remote = self.cfg.get(RecordConfig).foxglove_allow_remote
            return LiveView(host, port, name=f"bipedtele {self.role} {self.keys.root}", allow_remote=remote)
        except ModuleNotFoundError:
            raise ConfigError(
                "record.foxglove: the python package aiohttp is missing: allowed: pip install 'bipedtele[foxglove]'"
            ) from None
        except (RuntimeError, OSError) as exc:
            raise ConfigError(f"record.foxglove = {address!r}: cannot listen ({exc}); allowed: a free port") from None

    def record(self, topic: str, msg: Any, t: float) -> None:
        """Write one record (no-op when the run records nothing)."""
        if self.recorder is not None:
            self.recorder.write(topic, msg, t)

    def event(self, name: str, detail: dict[str, Any], t: float | None = None) -> None:
        """Record an event ``{"event": name, **detail}`` at ``t`` (default: now)."""
        self.record("events", {"event": name, **detail}, time.time() if t is None else t)

    def send(self, pub: MessagePublisher, msg: Message, topic: str | None = None) -> None:
        """Publish ``msg`` and record it under ``topic`` (None: not recorded)."""
        pub.put(msg)
        if topic is not None:
            self.record(topic, msg, time.time())

    # ------------------------------------------------------------------ declarations

    def declare_presence(self) -> None:
        """Declare this node alive under its role until it closes."""
        self.enter(declare_presence(self.session, self.keys, self.role))

    def watch_presence(self, role: str) -> PresenceWatcher:
        """Watch whether a peer of ``role`` is alive."""
        return self.enter(PresenceWatcher(self.session, self.keys, role))

    def receive(
        self,
        key: str,
        expect: type[M],
        gate: MessageGate | None,
        *,
        topic: str | None = None,
        estimator: DelayEstimator | None = None,
        on_message: Callable[[Received[M]], None] | None = None,
        ignore_sid: int | None = None,
        max_age_s: float | Callable[[float], float] | None = None,
        on_too_old: Callable[[Received[M]], None] | None = None,
        inbox: Callable[..., LatestInbox[M]] | None = None,
    ) -> LatestReceiver[M]:
        """Declare a receiver of ``key`` with the node's checks; it lives as long as the node.

        Parameters
        ----------
        key : str
            Key expression.
        expect : type
            The message class accepted.
        gate : MessageGate or None
            Drops stale and duplicated messages: the only de-duplication on the way in.
        topic : str, optional
            Every accepted message is recorded under this topic, once, in the receiver.
        estimator : DelayEstimator, optional
            Fed with every accepted message (send and receive time).
        on_message : callable, optional
            Called with every accepted message in Zenoh's callback thread (keep it short).
        ignore_sid : int, optional
            Messages of this session (our own on a shared key) are ignored.
        max_age_s : float or callable, optional
            Messages sent longer ago are dropped (``too_old``) before the gate and the
            estimator see them (a callable gets the receive time and returns the bound).
        on_too_old : callable, optional
            Called with each message refused as too old, instead of counting it.
        inbox : callable, optional
            Builds the inbox that admits the messages (a command or feedback inbox, with
            the node's checks; :class:`~bipedtele.link.receivers.LatestReceiver`).
        """
        accepted = self._accepted(key, topic, on_message)
        gate, max_age_s = live_checks(self, key, gate, max_age_s)  # video and status: bound, never old
        # commands and feedback: under the session key only (with the message key)
        hs = self.handshake if key in (self.keys.cmd, self.keys.feedback) else None
        auth = self.video_auth if key == self.keys.video else self.watch_auth if key == self.keys.status else self.auth
        rx: LatestReceiver[M] = LatestReceiver(
            self.session,
            key,
            expect,
            self.drops,
            gate,
            estimator=estimator,
            clock_sync=self.sync,
            auth=auth,
            max_future_s=self.max_future_s,
            ignore_sid=ignore_sid,
            on_message=accepted,
            max_age_s=max_age_s,
            on_too_old=on_too_old,
            handshake=hs,
            inbox=inbox,
        )
        return self.enter(rx)

    def _accepted(
        self, key: str, topic: str | None, on_message: Callable[[Received[M]], None] | None
    ) -> Callable[[Received[M]], None] | None:
        """Return what :meth:`receive` does with every accepted message of ``key`` (None: nothing).

        The drop counter hears an authentic message (with the message key), the relinking
        session a live control or status one, the recorder records it under ``topic``, and
        ``on_message`` gets it.
        """
        record, recorder = self.record, self.recorder
        authentic = self.drops.authentic if self.auth is not None else None
        heard = None
        if self._relink is not None and key in (self.keys.cmd, self.keys.feedback):
            heard = self._relink.heard
        elif self._relink is not None and key == self.keys.status:
            heard = self._relink.heard_status
        recorded = topic is not None and recorder is not None
        if not (recorded or on_message is not None or authentic is not None or heard is not None):
            return None

        def accepted(got: Received[M]) -> None:
            if authentic is not None:
                authentic()
            if heard is not None:
                heard()
            if topic is not None and recorder is not None:
                record(topic, got.msg, got.t_recv)
            if on_message is not None:
                on_message(got)

        return accepted

    def link_clocks(self, peer_sid: Callable[[], int | None]) -> ClockLink:
        """Start the clock link (answers pings; pings in ntp mode) bound to ``peer_sid()``."""
        ck = self.cfg.get(ClockConfig)
        link = self.enter(
            ClockLink(
                self.pubs.clock.put,
                self.sid,
                sync=self.sync,
                drops=self.drops,
                ping_rate_hz=ck.ping_rate_hz,
                answer_rate_hz=ck.answer_rate_hz,
                peer_sid=peer_sid,
                # the follower also answers leader sessions that completed the handshake (one
                # waiting for a robot another operator holds syncs and reads its status)
                also_answer=self.handshake.answers if self.handshake is not None and self.role == "follower" else None,
            )
        )
        # The clock receiver gets no clock conversion, future check nor gate: pings are
        # stamped on the peer's clock, and the link does its own matching. With the key,
        # the handshake's Hellos travel on the clock key too (both roles may publish it).
        hs = self.handshake
        kinds: tuple[type[Message], ...] = (ClockPing, ClockPong) if hs is None else (ClockPing, ClockPong, Hello)
        on_clock: Callable[[Received[Any]], None] = link.on_message
        if hs is not None:

            def hello_or_clock(got: Received[Any], _link: Callable[[Received[Any]], None] = link.on_message) -> None:
                self._heard()
                if isinstance(got.msg, Hello):
                    hs.on_hello(got.msg)
                else:
                    _link(got)

            on_clock = hello_or_clock
            self._start_hellos(hs)
        self.enter(
            LatestReceiver(
                self.session,
                self.keys.clock,
                kinds,
                self.drops,
                ignore_sid=self.sid,
                auth=self.auth,
                on_message=on_clock,
            )
        )
        return link

    def _start_hellos(self, hs: Handshake) -> None:
        """Send the handshake's Hellos from a side thread until the node closes."""
        put = self.pubs.clock.put
        done = threading.Event()

        def run() -> None:
            while not done.is_set():
                try:
                    for hello in hs.due():
                        put(hello)
                except Exception as exc:  # a bad moment on the network must not end the thread
                    LOG.warning("handshake: %s", exc)
                hs.changed.wait(0.05)
                done.wait(0.005)

        thread = threading.Thread(target=run, name=f"{self.role}-hello", daemon=True)
        thread.start()

        def stop() -> None:
            done.set()
            hs.changed.set()
            thread.join(2.0)

        self.on_close(stop)

    # ------------------------------------------------------------------ clocks

    def to_local(self, t: float) -> float:
        """Convert a peer's send time to the local clock (identity unless in ntp mode)."""
        return self.sync.to_local(t) if self.sync is not None else t

    def round_trip(self) -> float | None:
        """Return the measured round trip [s] when delays are split conservatively, else None.

        ntp mode with ``[clock] conservative_split``: across two clocks the round trip is
        exact but its split is not, so the control laws take ``h1 = h2 = rtt``.
        """
        if self.sync is None or not self._conservative_split:
            return None
        rtt = self.sync.rtt
        return None if rtt is None else float(rtt)
