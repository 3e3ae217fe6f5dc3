"""The router's access control is deny by default: only the leader reaches the robot.

A real ``bipedtele router`` process with user/password authentication and the roles
``publishers_allowed = ["leader"]``, ``followers_allowed = ["follower"]``; a third user,
``viewer``, has no role. Clients log in as each user:

- a non-leader (the follower's own identity, and the role-less viewer) puts commands on
  every key expression that covers the command key (``**``, ``bipedtele/**``,
  ``bipedtele/*/*``, ``bipedtele/nao1/*``, ``bipedtele/*/cmd`` and the exact key), with
  ``session.put`` (which a Zenoh client always hands to its router) and with a declared
  publisher, and declares a leader presence token: the follower's command subscriber
  receives none of it and sees no leader;
- the viewer subscribes to ``**`` and receives nothing;
- the leader's commands reach the follower, and the normal traffic flows both ways
  (feedback, video, status, clock, presence).
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import pytest
import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.drops import DropCounter
from bipedtele.link.messages import ClockPing, Command, Feedback, Status, VideoFrame, encode
from bipedtele.link.receivers import MessageReceiver
from bipedtele.link.transport import Keys, PresenceWatcher, Publishers, Stamper, declare_presence
from bipedtele.link.zenohsession import open_session

COMMAND_FORMS = ["**", "bipedtele/**", "bipedtele/*/*", "bipedtele/nao1/*", "bipedtele/*/cmd", "bipedtele/nao1/cmd"]
USERS = {"leader": "lpw", "follower": "fpw", "viewer": "vpw"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def acl_router(
    tmp_path: Path, users: dict[str, str] = USERS, leaders: str = '["leader"]', followers: str = '["follower"]'
) -> Iterator[str]:
    """A `bipedtele router` with credentials and both roles; yields its endpoint."""
    creds = tmp_path / "creds.txt"
    creds.write_text("".join(f"{u}:{p}\n" for u, p in users.items()))
    profile = tmp_path / "router.toml"
    profile.write_text(
        f'[network]\nmode = "router"\ncredentials_file = "{creds}"\n'
        f"publishers_allowed = {leaders}\nfollowers_allowed = {followers}\n"
    )
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen(
        [sys.executable, "-m", "bipedtele.cli", "router", "--config", str(profile), "--listen", ep],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        assert router.stdout is not None
        assert f"listening on {ep}" in router.stdout.readline()
        yield ep
    finally:
        router.send_signal(signal.SIGTERM)
        _, err = router.communicate(timeout=15)
        assert router.returncode == 0, err[-2000:]


class Tap:
    """Every sample of a raw subscriber: (key expression, payload)."""

    def __init__(self) -> None:
        self.samples: list[tuple[str, bytes]] = []
        self._lock = threading.Lock()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.samples.append((str(sample.key_expr), sample.payload.to_bytes()))

    def __len__(self) -> int:
        with self._lock:
            return len(self.samples)


def _until(cond: Callable[[], bool], step: Callable[[], None], timeout_s: float) -> bool:
    """Run ``step`` every 50 ms until ``cond`` holds or ``timeout_s`` passed."""
    end = time.monotonic() + timeout_s
    while not cond():
        if time.monotonic() > end:
            return False
        step()
        time.sleep(0.05)
    return True


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_only_the_leader_reaches_the_command_key(tmp_path: Path) -> None:
    keys = Keys("nao1")
    with acl_router(tmp_path) as ep, ExitStack() as stack:

        def login(user: str) -> zenoh.Session:
            net = NetworkConfig(mode="client", connect=[ep], user=user, password=USERS[user], timeout_s=5.0)
            return stack.enter_context(open_session(net))

        fs, rogue_f, rogue_v = login("follower"), login("follower"), login("viewer")
        lead, foll = Stamper(), Stamper()
        fdrops = DropCounter("follower")
        # ---- the follower: command subscriber (decoded, and raw: anything at all)
        f_cmd = stack.enter_context(MessageReceiver(fs, keys.cmd, Command, fdrops))
        f_raw = Tap()
        stack.callback(fs.declare_subscriber(keys.cmd, f_raw).undeclare)
        f_clock = stack.enter_context(MessageReceiver(fs, keys.clock, ClockPing, fdrops, ignore_sid=foll.sid))
        f_status = stack.enter_context(MessageReceiver(fs, keys.status, Status, fdrops, ignore_sid=foll.sid))
        f_sees_leader = stack.enter_context(PresenceWatcher(fs, keys, "leader"))
        stack.enter_context(declare_presence(fs, keys, "follower"))
        f_pubs = stack.enter_context(Publishers(fs, keys))
        # ---- the viewer listens to everything (in a session of its own: a session
        # receives its own puts locally)
        spy = Tap()
        stack.callback(login("viewer").declare_subscriber("**", spy).undeclare)
        # ---- non-leaders try to command the robot and to pass for a leader
        rogues = [(rogue_f, Stamper()), (rogue_v, Stamper())]
        for session, _ in rogues:
            stack.enter_context(declare_presence(session, keys, "leader"))
        rogue_pubs = [stack.enter_context(Publishers(s, keys)) for s, _ in rogues]

        def attack() -> None:
            for (session, st), pubs in zip(rogues, rogue_pubs, strict=True):
                for form in COMMAND_FORMS:
                    session.put(form, encode(st.make(Command, ref=[6.0, 0.0])))
                pubs.cmd.put(st.make(Command, ref=[6.0, 0.0]))

        for _ in range(20):
            attack()
            time.sleep(0.05)
        assert not f_sees_leader.wait(alive=True, timeout=1.0), "a non-leader's presence token passed for a leader"

        # ---- the leader joins: its commands and the normal traffic flow both ways
        ls = login("leader")
        ldrops = DropCounter("leader")
        l_rx = {
            "feedback": stack.enter_context(MessageReceiver(ls, keys.feedback, Feedback, ldrops)),
            "video": stack.enter_context(MessageReceiver(ls, keys.video, VideoFrame, ldrops)),
            "status": stack.enter_context(MessageReceiver(ls, keys.status, Status, ldrops, ignore_sid=lead.sid)),
            "clock": stack.enter_context(MessageReceiver(ls, keys.clock, ClockPing, ldrops, ignore_sid=lead.sid)),
        }
        l_sees_follower = stack.enter_context(PresenceWatcher(ls, keys, "follower"))
        stack.enter_context(declare_presence(ls, keys, "leader"))
        l_pubs = stack.enter_context(Publishers(ls, keys))
        got: dict[str, set[int]] = {k: set() for k in ("cmd", "f_clock", "f_status", *l_rx)}

        def exchange() -> None:
            l_pubs.cmd.put(lead.make(Command, ref=[1.0, 0.0]))
            l_pubs.clock.put(lead.make(ClockPing))
            l_pubs.status.put(lead.make(Status, role="leader", state="running"))
            f_pubs.feedback.put(foll.make(Feedback))
            f_pubs.video.put(foll.make(VideoFrame, jpeg=b"\xff\xd8\xff\xd9"))
            f_pubs.clock.put(foll.make(ClockPing))
            f_pubs.status.put(foll.make(Status, role="follower", state="standing"))
            attack()
            for name, rx in (("cmd", f_cmd), ("f_clock", f_clock), ("f_status", f_status), *l_rx.items()):
                got[name] |= {r.msg.sid for r in rx.drain()}

        ours = {"cmd": lead.sid, "f_clock": lead.sid, "f_status": lead.sid} | dict.fromkeys(l_rx, foll.sid)
        flowed = _until(
            lambda: all(ours[k] in got[k] for k in got) and f_sees_leader.alive and l_sees_follower.alive,
            exchange,
            15.0,
        )
        assert flowed, {k: sorted(v) for k, v in got.items()}
        for _ in range(10):  # the leader active, the attack goes on
            exchange()
            time.sleep(0.05)
        time.sleep(0.3)
        exchange()

    rogue_sids = {st.sid for _, st in rogues}
    assert got["cmd"] == {lead.sid}, f"commands from {got['cmd'] - {lead.sid}} reached the robot (rogues: {rogue_sids})"
    forms = sorted({k for k, _ in f_raw.samples})
    assert forms == [keys.cmd], f"samples on {forms} reached the command subscriber"
    assert len(f_raw) > 0 and fdrops.total == 0, fdrops.counts()
    assert got["f_clock"] == {lead.sid} and got["f_status"] == {lead.sid}  # no rogue clock/status either
    assert ldrops.total == 0, ldrops.counts()  # no rogue command reached the leader's keys either
    assert len(spy) == 0, f"the viewer received {len(spy)} samples, e.g. on {spy.samples[0][0]}"


BOUND = {"alice": "apw", "f1": "p1", "f2": "p2"}


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_a_leader_bound_to_one_robot_commands_that_robot_only(tmp_path: Path) -> None:
    """Issue 23 (per-robot authority), on a real router: ``publishers_allowed = ["alice@nao1"]``,
    followers ``f1@nao1`` and ``f2@nao2``. alice's commands on nao1's key reach f1; the same
    commands on nao2's key (and on every wildcard form) never reach f2; f1 cannot publish
    feedback as nao2."""
    k1, k2 = Keys("nao1"), Keys("nao2")
    with acl_router(tmp_path, BOUND, '["alice@nao1"]', '["f1@nao1", "f2@nao2"]') as ep, ExitStack() as stack:

        def login(user: str) -> zenoh.Session:
            net = NetworkConfig(mode="client", connect=[ep], user=user, password=BOUND[user], timeout_s=5.0)
            return stack.enter_context(open_session(net))

        alice, f1, f2 = login("alice"), login("f1"), login("f2")
        on1, on2 = Tap(), Tap()
        stack.callback(f1.declare_subscriber(k1.cmd, on1).undeclare)
        stack.callback(f2.declare_subscriber(k2.cmd, on2).undeclare)
        fb2 = Tap()
        # alice may not even listen there (a session of its own: a session gets its own puts locally)
        stack.callback(login("alice").declare_subscriber(k2.feedback, fb2).undeclare)
        st, sf = Stamper(), Stamper()

        def send() -> None:
            alice.put(k1.cmd, encode(st.make(Command, ref=[1.0, 0.0])))
            alice.put(k2.cmd, encode(st.make(Command, ref=[6.0, 0.0])))
            for form in ("**", "bipedtele/**", "bipedtele/*/*", "bipedtele/nao2/*", "bipedtele/*/cmd"):
                alice.put(form, encode(st.make(Command, ref=[6.0, 0.0])))
            f1.put(k2.feedback, encode(sf.make(Feedback)))

        assert _until(lambda: len(on1) >= 5, send, 15.0), "alice's commands never reached her own robot"
        for _ in range(10):
            send()
            time.sleep(0.05)
        time.sleep(0.3)
    assert {k for k, _ in on1.samples} == {k1.cmd}
    assert len(on2) == 0, f"{len(on2)} of alice's commands reached nao2 (on {sorted({k for k, _ in on2.samples})})"
    assert len(fb2) == 0, "f1 published feedback as nao2"
