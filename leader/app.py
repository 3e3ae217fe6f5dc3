"""``bipedtele leader``: the operator's side as a program.

Opens the Zenoh session from ``[network]``, declares the leader's presence, publishes
commands (and status, and clock pings in ``[clock] mode = "ntp"``), receives feedback,
status and video, serves the browser cockpit, records everything to MCAP and runs the
1 kHz :class:`~bipedtele.leader.loop.LeaderLoop` in the main thread until the operator
model is done, ``--duration`` passed, or SIGINT/SIGTERM. On the way out it sends
``enable = false`` commands so the robot stops at once, then prints a one-line summary.

Order: arguments and configuration are checked first (one line, exit 2), then the session
opens and the device connects; only then does the cockpit serve (its address, with the
run's access token, is logged as ``cockpit: open http://HOST:PORT/?token=TOKEN``) and the
recording start. While the follower is present, :class:`~bipedtele.leader.reach.CommandReach`
watches that its feedback acknowledges our commands: if none does for 1.5 s a WARNING says
``commands not reaching the robot: refused by the router's ACL?``, and a run in which none
ever got through ends with exit code :data:`EXIT_NOT_REACHED` (3).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import os
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from bipedtele.auth import load_message_auth
from bipedtele.cli import add_config_args, config_from_args
from bipedtele.clock import ClockSync, DelayEstimator
from bipedtele.clocklink import ClockLink
from bipedtele.config import Config, ConfigError
from bipedtele.drops import DropCounter
from bipedtele.gate import SequenceGate
from bipedtele.leader.device import DeviceError, LeaderDevice, make_device
from bipedtele.leader.devices import SimFalcon, SimFalconParams
from bipedtele.leader.loop import LeaderLoop
from bipedtele.leader.operators import OPERATORS, Operator, course_from_config, make_operator
from bipedtele.leader.predictor import DelayPredictor, LivePredictor, prediction_fields
from bipedtele.leader.reach import CommandReach
from bipedtele.messages import (
    ClockPing,
    ClockPong,
    Command,
    Feedback,
    Status,
    VideoFrame,
    new_session_id,
)
from bipedtele.shutdown import shutdown_on_signals
from bipedtele.transport import (
    Keys,
    LatestReceiver,
    PresenceWatcher,
    Publishers,
    Received,
    declare_presence,
    open_session,
)

__all__ = ["add_leader_parser", "main"]

LOG = logging.getLogger(__name__)


def _make_device(cfg: Config, name: str) -> LeaderDevice:
    lc = cfg.section("leader")
    if name == "sim-falcon":
        params = SimFalconParams(
            mass_kg=lc.mass_kg, viscous_n_s_m=lc.viscous_n_s_m, coulomb_n=lc.coulomb_n,
            gravity_n=(lc.gravity_n[0], lc.gravity_n[1]),
        )  # fmt: skip
        return SimFalcon(params)
    try:
        # Hardware drivers read their own section ([falcon], [joystick]) from the profile.
        return make_device(name, config=cfg)
    except ValueError as exc:
        raise ConfigError(f"--device {name!r}: {exc}") from None


class _Aux:
    """The leader's slow duties in a side thread (about 20 Hz): status out, follower status
    in, presence, events of the operator's progress, the command-reach check. (Clock pings
    run in their own :class:`~bipedtele.clocklink.ClockLink` thread.)"""

    def __init__(
        self, loop: LeaderLoop, pubs: Publishers, cfg: Config, status_rx: LatestReceiver[Status],
        presence: PresenceWatcher, drops: DropCounter, record: Callable[[str, Any, float], None],
        reach: CommandReach | None = None,
    ) -> None:  # fmt: skip
        self.reach = reach
        self.loop, self.pubs, self.cfg = loop, pubs, cfg
        self.status_rx, self.presence = status_rx, presence
        self.drops, self.record = drops, record
        self.follower_status: Status | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="leader-aux", daemon=True)
        self._status_seq = 0
        self._passes = 0
        self._progress_lock = threading.Lock()

    def record_progress(self, now: float) -> None:
        """Record a ``pass`` event for every pass the operator completed since the last call."""
        op = self.loop.operator
        if op is None:
            return
        with self._progress_lock:
            prog = op.progress()
            n = int(prog.get("passes_done", 0))
            sides = list(prog.get("sides", []))
            while self._passes < n:
                self._passes += 1
                side = sides[self._passes - 1] if len(sides) >= self._passes else ""
                self.record("events", {"event": "pass", "n": self._passes, "side": side}, now)

    def __enter__(self) -> _Aux:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(5.0)

    def extras(self) -> dict[str, Any]:
        """Cockpit fields from the follower's status and the link."""
        st = self.follower_status
        out: dict[str, Any] = {"follower_present": self.presence.alive}
        if st is not None:
            out["watchdog"] = st.counters.get("watchdog_stops", st.counters.get("watchdog", 0))
            out["falls"] = st.counters.get("falls", 0)
            out["collisions"] = st.counters.get("collisions", 0)
            out["follower_text"] = st.text
        if not self.presence.alive:
            out["link"] = "no follower"
        return out

    def _run(self) -> None:
        lc, ck = self.cfg.section("leader"), self.cfg.section("clock")
        next_status = time.monotonic()
        text = "clock: synced" if ck.mode == "synced" else "clock: ntp (h1+h2 exact, split estimated)"
        while not self._stop.wait(0.05):
            now_m, now = time.monotonic(), time.time()
            try:
                got = self.status_rx.take()
                if got is not None:
                    self.follower_status = got.msg
                if now_m >= next_status:
                    next_status = now_m + 1.0 / lc.status_rate_hz
                    counters = {f"drop_{k}": v for k, v in self.drops.counts().items()}
                    counters.update(commands=self.loop.seq, feedback=self.loop.feedback_count,
                                    missed_ticks=self.loop.missed_ticks)  # fmt: skip
                    self._status_seq += 1
                    st = Status(sid=self.loop.sid, seq=self._status_seq, t=now, role="leader",
                                state=self.loop.state, counters=counters, text=text)  # fmt: skip
                    self.pubs.status.put(st)
                    self.record("status/sent", st, now)
                self.record_progress(now)
                if self.reach is not None:
                    self.reach.check(self.presence.alive)
            except Exception as exc:  # a bad moment on the network must not end the program
                LOG.warning("leader side thread: %s", exc)


#: Exit code of a run in which the follower was there but none of our commands reached it.
EXIT_NOT_REACHED = 3
#: Environment variable that sets the cockpit token instead of a random one (a launcher
#: that opens the page itself); URL-safe, at least 16 characters.
COCKPIT_TOKEN_ENV = "BIPEDTELE_COCKPIT_TOKEN"


def _cockpit_token() -> str | None:
    value = os.environ.get(COCKPIT_TOKEN_ENV)
    if value is None:
        return None
    from bipedtele.leader.cockpit.server import check_token

    try:
        return check_token(value)
    except ValueError as exc:
        raise ConfigError(f"{COCKPIT_TOKEN_ENV}: {exc}") from None


def main(
    cfg: Config,
    *,
    operator_name: str | None = None,
    device_name: str | None = None,
    duration_s: float | None = None,
    realtime: bool | None = None,
    record: Path | None = None,
    stats: dict[str, Any] | None = None,
) -> int:
    """Run the leader program. Returns the exit code (0: clean end; 1: the device failed;
    :data:`EXIT_NOT_REACHED`: the follower was there but none of our commands reached it).

    Nothing is served or recorded before the configuration is valid and the Zenoh session
    is open: the cockpit and the recording start after both.

    Parameters
    ----------
    cfg : Config
        Loaded profile.
    operator_name, device_name : str, optional
        Override ``[leader] operator`` / ``device``.
    duration_s : float, optional
        Stop after this long [s] (``[leader] duration_s`` when omitted; 0 = no limit). With
        a duration the scripted operator holds its last point's speed until the end
        instead of ending the run.
    realtime : bool, optional
        Override ``[leader] realtime``. Off runs the loop as fast as possible with message
        times on a virtual clock (tests and tools only: a real-time follower sees it as
        time passing faster).
    record : Path, optional
        MCAP file (default: a new file in ``[record] dir`` when recording is enabled).
    stats : dict, optional
        Filled at the end with the loop's figures (period statistics, counters, progress).
    """
    lc = cfg.section("leader")
    op_name = operator_name or lc.operator
    dev_name = device_name or lc.device
    rt = lc.realtime if realtime is None else realtime
    duration = lc.duration_s if duration_s is None else duration_s
    if op_name not in OPERATORS:
        raise ConfigError(f"--operator {op_name!r}: allowed: {', '.join(OPERATORS)}")
    if op_name == "browser" and not lc.cockpit:
        raise ConfigError("--operator browser: allowed only with the cockpit (leader.cockpit = true)")
    if record is not None and record.exists():
        raise ConfigError(f"--record {record}: the file exists; allowed: a new file (never overwritten)")
    device = _make_device(cfg, dev_name)  # a bad name fails here, before any I/O
    token = _cockpit_token() if lc.cockpit else None
    cockpit_ref: list[Any] = []  # the cockpit, once it runs (the browser operator reads it)

    def joystick() -> tuple[float, float, float] | None:
        return cockpit_ref[0].joystick() if cockpit_ref else None

    try:
        operator: Operator | None = make_operator(
            op_name, cfg, workspace_m=device.limits.workspace_m,
            joystick=joystick if lc.cockpit else None, hold_script=bool(duration),
        )  # fmt: skip
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if not isinstance(device, SimFalcon):
        operator = None  # a person holds a physical device
        LOG.info("device %s is held by a person: operator model %s not used", dev_name, op_name)
    keys = Keys(cfg.section("robot").id)
    ck = cfg.section("clock")
    ntp = ck.mode == "ntp"
    sync = ClockSync(ck.ping_window) if ntp else None
    rec_cfg = cfg.section("record")
    auth = load_message_auth(cfg.section("network"))  # a bad key file fails here, before any I/O
    drops = DropCounter("leader")
    estimator = DelayEstimator(ck.delay_window_s)
    sid = new_session_id()
    # The feedback gate follows one follower session; its live sid binds the clock link.
    fb_gate = SequenceGate(takeover_after_s=lc.feedback_timeout_s)
    loop_ref: list[LeaderLoop] = []
    reach = CommandReach(lambda: loop_ref[0].seq if loop_ref else 0)

    with contextlib.ExitStack() as stack:
        stop = stack.enter_context(shutdown_on_signals())
        # Python threads (Zenoh callbacks, cockpit, recorder) hand the GIL back to the
        # haptic loop sooner than the default 5 ms.
        stack.callback(sys.setswitchinterval, sys.getswitchinterval())
        sys.setswitchinterval(0.0005)

        session = stack.enter_context(open_session(cfg.section("network")))
        pubs = stack.enter_context(Publishers(session, keys, auth=auth))
        stack.enter_context(declare_presence(session, keys, "leader"))
        presence = stack.enter_context(PresenceWatcher(session, keys, "follower"))
        try:
            stack.enter_context(device)
        except DeviceError as exc:
            LOG.error("device %s: %s", dev_name, exc)
            return 1

        # Configuration, session and device are good: now the cockpit and the recording.
        cockpit = None
        if lc.cockpit:
            from bipedtele.leader.cockpit import CockpitServer

            try:
                cockpit = CockpitServer(
                    lc.cockpit_host, lc.cockpit_port, telemetry_hz=lc.cockpit_rate_hz, token=token,
                    allowed_hosts=lc.cockpit_allowed_hosts, max_clients=lc.cockpit_max_clients,
                    course=_map_course(cfg),
                ).start()  # fmt: skip
            except OSError as exc:
                raise ConfigError(
                    f"leader.cockpit_port = {lc.cockpit_port}: cannot serve on {lc.cockpit_host} "
                    f"({exc.strerror or exc}); allowed: a free port, or 0 for any"
                ) from None
            stack.callback(cockpit.stop)
            cockpit_ref.append(cockpit)
        recorder = None
        if record is not None or rec_cfg.enabled:
            from bipedtele.recording import recording_for_run

            recorder = stack.enter_context(recording_for_run(
                record, rec_cfg.dir, "leader", flush_s=rec_cfg.flush_s, jpeg_every=10,
                metadata={"role": "leader", "operator": op_name, "device": dev_name, "config": cfg.to_dict()},
            ))  # fmt: skip
            record = recorder.path

        def rec(topic: str, msg: Any, t: float) -> None:
            if recorder is not None:
                recorder.write(topic, msg, t)

        def on_feedback(r: Received[Any]) -> None:
            reach.on_feedback(r.msg)
            rec("feedback/recv", r.msg, r.t_recv)

        def on_video(r: Received[Any]) -> None:
            msg: VideoFrame = r.msg
            if cockpit is not None:
                cockpit.publish_video(msg.camera, msg.jpeg, msg.t_capture)
            rec("video/recv", msg, r.t_recv)

        def on_status(r: Received[Any]) -> None:
            rec("status/recv", r.msg, r.t_recv)

        # Every stamped message: authenticated (when a key is set), converted to our clock
        # (ntp) and dropped when stamped too far ahead of it.
        checks: dict[str, Any] = dict(auth=auth, clock_sync=sync, max_future_s=ck.max_future_s)
        fb_rx: LatestReceiver[Feedback] = stack.enter_context(LatestReceiver(
            session, keys.feedback, Feedback, drops, fb_gate, estimator=estimator,
            on_message=on_feedback, **checks,
        ))  # fmt: skip
        stack.enter_context(LatestReceiver(
            session, keys.video, VideoFrame, drops, SequenceGate(), on_message=on_video, **checks,
        ))  # fmt: skip
        status_rx: LatestReceiver[Status] = stack.enter_context(LatestReceiver(
            session, keys.status, Status, drops, SequenceGate(), on_message=on_status, ignore_sid=sid, **checks,
        ))  # fmt: skip
        # Clock pings: answered and sent off the haptic loop, bound to the followed follower.
        link = stack.enter_context(ClockLink(
            pubs.clock.put, sid, sync=sync, drops=drops, ping_rate_hz=ck.ping_rate_hz,
            answer_rate_hz=ck.answer_rate_hz, peer_sid=lambda: fb_gate.live_sid,
        ))  # fmt: skip
        stack.enter_context(LatestReceiver(
            session, keys.clock, (ClockPing, ClockPong), drops, ignore_sid=sid, auth=auth,
            on_message=link.on_message,
        ))  # fmt: skip

        def latest_feedback() -> tuple[Feedback, float] | None:
            got = fb_rx.latest()
            return (got.msg, got.t_recv) if got is not None else None

        def send_command(cmd: Command) -> None:
            pubs.cmd.put(cmd)
            rec("cmd/sent", cmd, cmd.t)

        aux_holder: list[_Aux] = []
        # The predictive display's fields (docs/cockpit.md): the pilot's own predictor when
        # it steers on one, else one fed here from the same samples.
        live = getattr(operator, "live", None)
        own_live = live is None
        if own_live:
            live = LivePredictor(DelayPredictor(tau_s=lc.pilot_predict_tau_s))
        predict_every = max(1, round(lc.cmd_rate_hz / lc.cockpit_rate_hz))

        def on_sample(snap: dict[str, Any]) -> None:  # the loop fed the operator already
            if live is not None and loop_ref:
                fb = loop_ref[0].feedback
                if own_live:
                    live.observe(snap, fb.t if fb is not None else None)
                    if fb is not None and snap["seq"] % predict_every == 0:
                        live.predict(snap["t"], fb.pose, fb.eta, fb.t, fb.h1_s)
                snap.update(prediction_fields(live.last))
            if aux_holder:
                snap.update(aux_holder[0].extras())
            if cockpit is not None:
                cockpit.publish_sample(snap)
            rec("leader/state", snap, snap["t"])

        ticks = [0]
        if rt:
            clock: Callable[[], float] = time.time
        else:
            t0_wall = time.time()

            def clock() -> float:
                return t0_wall + ticks[0] * (1.0 / lc.haptic_rate_hz)

        rtt_fn: Callable[[], float | None] | None = None
        if sync is not None and ck.conservative_split:
            ntp_sync = sync

            def rtt_fn() -> float | None:  # read at every use: the estimate improves
                return ntp_sync.rtt
        loop = LeaderLoop(
            device, operator, cfg.section("control"), send_command, latest_feedback, cfg=lc,
            clock=clock, estimator=estimator, conservative_rtt=rtt_fn, on_sample=on_sample, sid=sid,
        )  # fmt: skip
        loop_ref.append(loop)
        aux = stack.enter_context(_Aux(loop, pubs, cfg, status_rx, presence, drops, rec, reach))
        aux_holder.append(aux)
        LOG.info(
            "leader ready: robot %s, device %s, operator %s, %s%s", cfg.section("robot").id, dev_name,
            op_name if operator is not None else "(person)", "real time" if rt else "as fast as possible",
            f", cockpit {cockpit.url}" if cockpit is not None else "",
        )  # fmt: skip
        if cockpit is not None:
            LOG.info("cockpit: open %s", cockpit.url)
        rec("events", {"event": "start", "operator": op_name}, time.time())
        t_start = time.time()
        if rt:
            loop.run(stop=stop, duration_s=duration or None, until_done=True)
        else:
            limit = round(duration * lc.haptic_rate_hz) if duration else None
            while not stop.is_set() and not loop.done and (limit is None or ticks[0] < limit):
                loop.tick(now=clock())
                ticks[0] += 1
        elapsed = time.time() - t_start
        done = loop.done
        aux.record_progress(time.time())  # the last pass may have ended the run just now
        rec("events", {"event": "done" if done else "stop", "elapsed_s": elapsed}, time.time())
        loop.send_stop()
        never_reached = reach.never_reached
        if never_reached:
            rec("events", {"event": "commands_not_reaching", "commands": loop.seq}, time.time())
        summary = _summary(loop, op_name, operator, elapsed, drops, record, rt, reach)
        if stats is not None:
            stats.update(loop.period_stats.summary(loop.dt))
            stats.update(
                missed_ticks=loop.missed_ticks, commands=loop.seq, feedback=loop.feedback_count,
                drops=drops.total, done=done, elapsed_s=elapsed,
                progress=operator.progress() if operator is not None else {},
                cockpit=cockpit.stats if cockpit is not None else {},
                acknowledged=reach.acknowledged, never_reached=never_reached,
                slew_limited_ticks=loop.slew_limited_ticks,
            )  # fmt: skip
    print(summary, flush=True)  # noqa: T201 - the program's one-line result
    return EXIT_NOT_REACHED if never_reached else 0


def _map_course(cfg: Config) -> list[tuple[float, float, float]]:
    """The obstacles the cockpit's map draws (the pilot's course: ``[leader]
    pilot_obstacles``, else the ``[world]`` obstacles); empty when neither is set."""
    lc, world = cfg.section("leader"), cfg.sections.get("world")
    if not lc.pilot_obstacles and not getattr(world, "obstacles", None):
        return []
    try:
        return [(o.x, o.y, o.radius) for o in course_from_config(cfg)]
    except ValueError as exc:
        LOG.warning("cockpit map: no obstacles (%s)", exc)
        return []


def _summary(
    loop: LeaderLoop, op_name: str, operator: Operator | None, elapsed: float,
    drops: DropCounter, record: Path | None, rt: bool, reach: CommandReach | None = None,
) -> str:  # fmt: skip
    parts = [f"leader: operator {op_name}"]
    prog = operator.progress() if operator is not None else {}
    if "passes_done" in prog:
        parts.append(f"{prog['passes_done']}/{prog['passes']} passes")
    parts.append("done" if loop.done else "stopped")
    parts.append(f"{elapsed:.1f} s")
    parts.append(f"{loop.seq} commands sent, {loop.feedback_count} feedback received, {drops.total} dropped")
    if loop.h1 is not None and loop.h2 is not None:
        parts.append(f"last delay h1+h2 {1000 * (loop.h1 + loop.h2):.0f} ms")
    parts.append(f"max |f_m| now {float(np.abs(loop.force).max()):.2f} N")
    if rt:
        st = loop.period_stats.summary(loop.dt)
        if "rate_hz" in st:
            parts.append(f"loop {st['rate_hz']:.1f} Hz, p99 period error {1000 * st['err_p99_s']:.2f} ms")
    if record is not None:
        parts.append(f"recording {record}")
    if reach is not None and reach.never_reached:
        parts.append("NO COMMAND REACHED THE ROBOT (refused by the router's ACL? log in as a leader user)")
    return ", ".join(parts)


def _run(args: argparse.Namespace) -> int:
    cfg = config_from_args(args)
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration >= 0):
        raise ConfigError(f"--duration {args.duration}: allowed: a number of seconds >= 0")
    realtime = None if args.realtime is None else args.realtime == "on"
    return main(
        cfg, operator_name=args.operator, device_name=args.device, duration_s=args.duration,
        realtime=realtime, record=Path(args.record) if args.record else None,
    )  # fmt: skip


def add_leader_parser(sub: Any) -> None:
    """``bipedtele leader``: run the operator's side."""
    p = sub.add_parser("leader", help="run the operator's side (haptic device, operator model, cockpit)")
    add_config_args(p)
    p.add_argument("--operator", choices=OPERATORS, help="operator model (default: [leader] operator)")
    p.add_argument("--device", help="leader device, e.g. sim-falcon (default: [leader] device)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (0: no limit)")
    p.add_argument("--realtime", choices=["on", "off"], help="pace in real time (default: [leader] realtime)")
    p.add_argument("--record", metavar="FILE", help="MCAP file (default: a new leader-<time>.mcap in [record] dir)")
    p.set_defaults(func=_run)
