"""An attacker on a robot's Zenoh network, for the adversary tests and ``bench/adversary.py``.

Run as a program, one attack per sub-command (every loop bounded in count and time)::

    python tests/e2e/adversary_support.py ATTACK --connect tcp/127.0.0.1:7447 [--user U --password P] ...

``commands``     Commands (enable, a forward speed, fresh stamps, its own session ids) on
                 each of ``--keys`` in turn (wildcards allowed: ``**``, ``bipedtele/*/*``).
``poison``       One Command with the leader's sid (seen on ``cmd``) and ``seq = 2**63 - 1``.
``future``       One Command and/or one Feedback stamped ``--ahead`` seconds in the future,
                 with the sid of the real sender and the sequence number following the
                 last one seen (so that no sequence check can tell it from the real one).
``stream``       A plausible leader (Commands) or follower (Feedback) stream whose stamps are
                 shifted by ``--shift`` seconds (a peer whose clock is off).
``clock-forge``  Forged ClockPong answers: to the pings it sees (forged t2/t3 that shift the
                 offset by ``--offset`` and make the round trip look near zero) and to pings
                 never sent; from its own sid, or spoofing the other node's sid (``--as peer``).
``flood``        ClockPings at ``--rate`` per second for ``--seconds``; counts who answered.
``compromised``  What a compromised router can do to a run protected by a message key:
                 replays recorded command and feedback payloads verbatim, sends copies with a
                 fresh time patched into the signed bytes (sealed: none readable, a bit flipped
                 instead), and unsigned forged commands (the leader's sid, or sealed, a guess).

Each prints one JSON line with what it sent (and saw). Imported, the module gives the tests
their helpers: profiles with users, a message key file, status counters from recordings.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import secrets
import struct
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MAX_SEQ = 2**63 - 1
MAX_SECONDS = 120.0

# --------------------------------------------------------------------------- test helpers


@dataclass
class Users:
    """Credentials of a router and the files its clients read.

    Attributes
    ----------
    creds : Path
        The router's ``user:password`` file.
    passwords : dict
        User -> password.
    password_files : dict
        User -> file holding the password (mode 0600).
    """

    creds: Path
    passwords: dict[str, str] = field(default_factory=dict)
    password_files: dict[str, Path] = field(default_factory=dict)

    def client_args(self, user: str) -> list[str]:
        """Overrides that log a leader or follower in as ``user``."""
        return ["--set", f'network.user="{user}"', "--set", f'network.password_file="{self.password_files[user]}"']

    def attacker_args(self, user: str) -> list[str]:
        """Arguments of this program that log it in as ``user``."""
        return ["--user", user, "--password", self.passwords[user]]


def make_users(folder: Path, names: list[str]) -> Users:
    """Write a credentials file and one password file per user (random passwords)."""
    folder.mkdir(parents=True, exist_ok=True)
    users = Users(folder / "creds.txt")
    for name in names:
        users.passwords[name] = f"{name}-{secrets.token_hex(6)}"
        pw = folder / f"{name}.pw"
        pw.write_text(users.passwords[name] + "\n")
        pw.chmod(0o600)
        users.password_files[name] = pw
    users.creds.write_text("".join(f"{n}:{p}\n" for n, p in users.passwords.items()))
    users.creds.chmod(0o600)
    return users


def router_profile(folder: Path, users: Users, leaders: list[str], followers: list[str]) -> Path:
    """A router profile: user/password required, the leader and follower roles by user."""
    text = (
        "[network]\n"
        f'credentials_file = "{users.creds}"\n'
        f"publishers_allowed = {json.dumps(leaders)}\n"
        f"followers_allowed = {json.dumps(followers)}\n"
        "timeout_s = 10.0\n"
    )
    path = folder / "router.toml"
    path.write_text(text)
    return path


def make_key_file(path: Path) -> Path:
    """A message key file: 32 random bytes as 64 hex characters, mode 0600."""
    path.write_text(secrets.token_hex(32) + "\n")
    path.chmod(0o600)
    return path


def counters(records: list[Any]) -> list[tuple[float, dict[str, int]]]:
    """``(t, counters)`` of the ``status/sent`` records of one recording, in order."""
    return [(r.t_recv, dict(r.data["counters"])) for r in records if r.topic == "status/sent"]


def drops(c: dict[str, int], *reasons: str) -> int:
    """Sum of ``drop_<reason>`` counters (every ``drop_*`` when no reason is given)."""
    if not reasons:
        return sum(v for k, v in c.items() if k.startswith("drop_"))
    return sum(c.get(f"drop_{r}", 0) for r in reasons)


def recorded_feedback(path: Path) -> list[tuple[float, str]]:
    """``(t, state)`` of the ``feedback/sent`` records a running follower has flushed so far."""
    from bipedtele.recording.format import RecordingError, read_records

    try:
        return [(r.data["t"], r.data["state"]) for r in read_records(path) if r.topic == "feedback/sent"]
    except (RecordingError, OSError):
        return []


def wait_recorded_state(path: Path, state: str, since: float, timeout_s: float, hold_s: float) -> float:
    """Wait until the follower's recording shows ``state`` from some t >= ``since`` for ``hold_s``.

    For runs whose messages are signed (a watcher without the key cannot read them): the
    follower's own recording is flushed about every second. Returns the stretch's first t.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        fbs = [(t, s) for t, s in recorded_feedback(path) if t >= since]
        start = None
        for t, s in fbs:
            start = (t if start is None else start) if s == state else None
        if start is not None and fbs[-1][0] - start >= hold_s:
            return start
        if time.monotonic() > deadline:
            raise AssertionError(
                f"no {state!r} for {hold_s:g} s in {path.name}: last states {[s for _, s in fbs[-10:]]}"
            )
        time.sleep(0.5)


def last_json(text: str) -> dict[str, Any]:
    """The last line of a program's output that is a JSON object."""
    for line in reversed(text.strip().splitlines()):
        if line.startswith("{"):
            out: dict[str, Any] = json.loads(line)
            return out
    raise AssertionError(f"no JSON line in:\n{text[-2000:]}")


# --------------------------------------------------------------------------- the attacker


class Attacker:
    """Zenoh client sessions with raw publishers and subscribers (no auth, no checks).

    The main session logs in with ``--user``/``--password``; with ``--user2`` a second
    session logs in as another user (``via="b"``), so that one attacker can hold two roles.
    """

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.sid = int.from_bytes(os.urandom(4), "little") or 7
        self.out: dict[str, Any] = {"opened": False, "error": None, "sid": self.sid}
        self.sessions: dict[str, Any] = {}
        self._pubs: dict[tuple[str, str], Any] = {}
        self._subs: list[Any] = []
        self._lock = threading.Lock()

    @contextmanager
    def session(self) -> Iterator[Any]:
        from contextlib import ExitStack

        from bipedtele.config.sections import NetworkConfig
        from bipedtele.link.zenohsession import open_session

        a = self.args
        logins = {"a": (a.user, a.password)}
        if getattr(a, "user2", ""):
            logins["b"] = (a.user2, a.password2)
        with ExitStack() as stack:
            for name, (user, password) in logins.items():
                net = NetworkConfig(
                    mode="client", connect=[a.connect], user=user, password=password, timeout_s=a.timeout
                )
                self.sessions[name] = stack.enter_context(open_session(net))
            self.out["opened"] = True
            try:
                yield self.sessions["a"]
            finally:
                time.sleep(0.3)  # let the last puts leave before the sessions close
                for sub in self._subs:
                    sub.undeclare()
                for p in self._pubs.values():
                    p.undeclare()

    def key(self, name: str) -> str:
        return f"bipedtele/{self.args.robot_id}/{name}"

    def put(self, key: str, payload: bytes, via: str = "a") -> None:
        import zenoh

        pub = self._pubs.get((via, key))
        if pub is None:
            # Block rather than drop: every forged payload must reach the receivers, so
            # that what they count can be compared with what was sent.
            pub = self.sessions[via].declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            self._pubs[(via, key)] = pub
        pub.put(payload)

    def subscribe(self, key: str, cb: Any, via: str = "a") -> None:
        def on_sample(sample: Any) -> None:
            try:
                cb(sample.payload.to_bytes(), time.time())
            except Exception as exc:  # an attacker's own parse errors do not matter
                with self._lock:
                    self.out.setdefault("callback_errors", 0)
                    self.out["callback_errors"] += 1
                    self.out["last_callback_error"] = repr(exc)

        self._subs.append(self.sessions[via].declare_subscriber(key, on_sample))


def _decode(payload: bytes) -> Any:
    """The message in a payload whatever frames it (a MAC before it), or None.

    Tries the payload, then every suffix that starts with a msgpack map header within
    the first 80 bytes (a signed payload carries the plain message after its tag).
    """
    from bipedtele.link.messages import MessageError, decode

    for i in range(min(len(payload), 80)):
        b = payload[i]
        if i and not (0x80 <= b <= 0x8F or b == 0xDE):
            continue
        try:
            return decode(payload[i:])
        except MessageError:
            continue
    return None


def _bounded(seconds: float) -> float:
    if not 0 <= seconds <= MAX_SECONDS:
        raise SystemExit(f"--seconds {seconds}: allowed: 0-{MAX_SECONDS:g}")
    return seconds


def cmd_commands(a: argparse.Namespace) -> dict[str, Any]:
    """Commands on each key expression in turn, alternating among ``--sids`` own session ids."""
    from bipedtele.link.messages import Command, encode

    att = Attacker(a)
    keys = [k.replace("{root}", f"bipedtele/{a.robot_id}") for k in a.keys.split(",")]
    sids = [att.sid] + [int.from_bytes(os.urandom(4), "little") or 9 for _ in range(a.sids - 1)]
    seqs = dict.fromkeys(sids, 0)
    sent: Counter[str] = Counter()
    period = 1.0 / a.rate
    try:
        with att.session():
            for key in keys:
                end = time.monotonic() + _bounded(a.seconds)
                i = 0
                while time.monotonic() < end and sent[key] < 10_000:
                    sid = sids[i % len(sids)]
                    seqs[sid] += 1
                    msg = Command(sid=sid, seq=seqs[sid], t=time.time(), ref=[a.forward, a.turn], enable=True)
                    att.put(key, encode(msg))
                    sent[key] += 1
                    i += 1
                    time.sleep(period)
    except Exception as exc:  # reported, e.g. a session the router refused
        att.out["error"] = f"{type(exc).__name__}: {exc}"
    att.out.update(sent=dict(sent), sids=sids)
    return att.out


def _wait_for(pred: Any, seconds: float) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return False


def cmd_poison(a: argparse.Namespace) -> dict[str, Any]:
    """One command with the leader's sid and the largest sequence number."""
    import msgspec
    from bipedtele.link.messages import Command, encode

    att = Attacker(a)
    seen: list[Any] = []
    with att.session():
        att.subscribe(att.key("cmd"), lambda p, t: seen.append(_decode(p)))
        if not _wait_for(lambda: any(isinstance(m, Command) for m in seen), a.seconds):
            att.out["error"] = "no command seen"
            return att.out
        real = next(m for m in seen if isinstance(m, Command))
        forged = msgspec.structs.replace(real, seq=MAX_SEQ, t=time.time())
        att.put(att.key("cmd"), encode(forged))
        att.out.update(leader_sid=real.sid, leader_seq=real.seq, seq=MAX_SEQ, t=forged.t)
    return att.out


def cmd_future(a: argparse.Namespace) -> dict[str, Any]:
    """One message per target, stamped ``--ahead`` s in the future, following the real sender.

    Targets are forged in the order given, ``--gap`` seconds apart, each right after a real
    message of its kind arrived (or, if none comes within 0.5 s, after the last one seen).
    """
    import msgspec
    from bipedtele.link.messages import Command, Feedback, encode

    att = Attacker(a)
    kinds = {"cmd": Command, "feedback": Feedback}
    targets = a.targets.split(",")
    last: dict[str, tuple[int, Any]] = {}  # kind -> (arrival number, message)
    done: dict[str, dict[str, Any]] = {}

    def on(name: str) -> Any:
        def cb(payload: bytes, t_recv: float) -> None:
            msg = _decode(payload)
            if isinstance(msg, kinds[name]) and msg.sid != att.sid:
                n = last[name][0] + 1 if name in last else 1
                last[name] = (n, msg)

        return cb

    with att.session():
        for name in targets:
            att.subscribe(att.key(name), on(name))
        for i, name in enumerate(targets):
            if i:
                time.sleep(a.gap)
            if not _wait_for(lambda name=name: name in last, a.seconds):
                att.out["error"] = f"no {name} seen"
                break
            n0 = last[name][0]
            _wait_for(lambda name=name, n0=n0: last[name][0] > n0, 0.5)
            msg = last[name][1]
            t = time.time() + a.ahead
            att.put(att.key(name), encode(msgspec.structs.replace(msg, seq=msg.seq + 1, t=t)))
            done[name] = {"sid": msg.sid, "seq": msg.seq + 1, "t": t, "t_put": time.time()}
    att.out["forged"] = done
    return att.out


def cmd_stream(a: argparse.Namespace) -> dict[str, Any]:
    """A plausible leader or follower stream from a peer whose clock is ``--shift`` s ahead."""
    from bipedtele.link.messages import Command, Feedback, encode

    att = Attacker(a)
    n = 0
    with att.session():
        end = time.monotonic() + _bounded(a.seconds)
        key = att.key(a.kind)
        while time.monotonic() < end and n < 20_000:
            n += 1
            t = time.time() + a.shift
            if a.kind == "cmd":
                msg: Any = Command(sid=att.sid, seq=n, t=t, ref=[a.forward, 0.0], alpha_m=[40.0, 40.0], enable=True)
            else:
                msg = Feedback(
                    sid=att.sid,
                    seq=n,
                    t=t,
                    z_e=[a.forward, 0.0],
                    z_r=[a.forward, 0.0],
                    eta=[a.forward, 0.0],
                    ref=[a.forward, 0.0],
                    s_e=[1.0, 1.0],
                    s_r=[1.0, 1.0],
                    T=1.0,
                    eps=0.1,
                    state="walking",
                    cmd_seq=0,
                )
            att.put(key, encode(msg))
            time.sleep(1.0 / a.rate)
    att.out.update(sent=n, shift=a.shift)
    return att.out


def cmd_clock_forge(a: argparse.Namespace) -> dict[str, Any]:
    """Forged clock answers: to seen pings (forged t2/t3) and to pings never sent."""
    from bipedtele.link.messages import ClockPing, ClockPong, Command, Feedback, encode

    att = Attacker(a)
    sids: dict[str, int] = {}  # role -> sid, learned from cmd (leader) and feedback (follower)
    last_ping: dict[int, tuple[int, float]] = {}  # pinger sid -> (seq, t1)
    sent: Counter[str] = Counter()
    sent_to: Counter[str] = Counter()  # pinger sid -> forged answers addressed to it
    lock = threading.Lock()
    seq = [0]

    def learn(role: str, cls: type[Any]) -> Any:
        def cb(payload: bytes, t_recv: float) -> None:
            msg = _decode(payload)
            if isinstance(msg, cls) and role not in sids:
                sids[role] = msg.sid

        return cb

    def responder_for(pinger: int) -> int:
        """Our own sid, or the sid of the node the pinger expects an answer from."""
        if a.as_ == "own":
            return att.sid
        other = "follower" if sids.get("leader") == pinger else "leader"
        return sids.get(other, att.sid)

    def back_path(pinger: int) -> float:
        """The answer's travel time to the pinger [s] (the leader is behind the delay proxy)."""
        return a.back_s if sids.get("leader") == pinger else 0.0

    def pong(pinger: int, ping_seq: int, t1: float, t2: float, t3: float, what: str) -> None:
        with lock:
            seq[0] += 1
            msg = ClockPong(
                sid=responder_for(pinger),
                seq=seq[0],
                t=t3,
                ping_sid=pinger,
                ping_seq=ping_seq,
                t1=t1,
                t2=t2,
            )
            att.put(att.key("clock"), encode(msg))
            sent[what] += 1
            sent_to[str(pinger)] += 1

    def on_clock(payload: bytes, t_recv: float) -> None:
        msg = _decode(payload)
        if not isinstance(msg, ClockPing) or msg.sid == att.sid or time.monotonic() > end:
            return
        last_ping[msg.sid] = (msg.seq, msg.t)
        # Matching answer: the real t1, a t2 that puts the pinger's peer --offset s ahead,
        # and a responder time t3 - t2 that leaves a near-zero round trip, which wins the
        # pinger's min-RTT filter: rtt = (t4 - t1) - (t3 - t2).
        fwd = max(0.0, t_recv - msg.t)
        hold = max(0.0, fwd + back_path(msg.sid) - a.shave_s)
        t2 = t_recv + a.offset
        pong(msg.sid, msg.seq, msg.t, t2, t2 + hold, "matching")

    if a.pingers:  # sids known beforehand (sealed traffic shows none): answers to pings never seen
        leader_sid, follower_sid = (int(x) for x in a.pingers.split(","))
        sids.update(leader=leader_sid, follower=follower_sid)
        last_ping.update({leader_sid: (0, 0.0), follower_sid: (0, 0.0)})
    end = time.monotonic() + _bounded(a.seconds)
    with att.session():
        att.subscribe(att.key("cmd"), learn("leader", Command))
        att.subscribe(att.key("feedback"), learn("follower", Feedback))
        att.subscribe(att.key("clock"), on_clock)
        n = 0
        while time.monotonic() < end and n < 10_000:
            time.sleep(1.0 / a.rate)
            n += 1
            now = time.time()
            for pinger, (last_seq, _) in list(last_ping.items()):
                # Answers to pings never sent: the next seq, and one far ahead; t1 is ours.
                t1 = now - 0.001
                t2 = now + a.offset
                hold = max(0.0, back_path(pinger) - a.shave_s)
                pong(pinger, last_seq + 1, t1, t2, t2 + hold, "unsolicited")
                pong(pinger, last_seq + 1000 + n, t1, t2, t2 + hold, "unsolicited")
    att.out.update(sent=dict(sent), sent_to=dict(sent_to), pingers=sorted(last_ping), learned=sids)
    return att.out


def cmd_flood(a: argparse.Namespace) -> dict[str, Any]:
    """ClockPings at ``--rate`` for ``--seconds`` (in 10 ms bursts); counts the answers to them."""
    from bipedtele.link.messages import ClockPing, ClockPong, encode

    att = Attacker(a)
    answered: Counter[int] = Counter()
    total = int(a.rate * _bounded(a.seconds))

    def on_clock(payload: bytes, t_recv: float) -> None:
        msg = _decode(payload)
        if isinstance(msg, ClockPong) and msg.ping_sid == att.sid:
            answered[msg.sid] += 1

    n = 0
    with att.session():
        att.subscribe(att.key("clock"), on_clock)
        key = att.key("clock")
        burst = max(1, int(a.rate / 100))
        t0 = time.monotonic()
        end = t0 + a.seconds
        next_burst = t0
        while n < total and time.monotonic() < end:
            for _ in range(min(burst, total - n)):
                n += 1
                att.put(key, encode(ClockPing(sid=att.sid, seq=n, t=time.time())))
            next_burst += 0.01
            delay = next_burst - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        elapsed = time.monotonic() - t0
        time.sleep(1.0)  # answers still on their way
    att.out.update(
        sent=n,
        elapsed_s=elapsed,
        rate_hz=n / elapsed if elapsed else 0.0,
        answered={str(k): v for k, v in answered.items()},
    )
    return att.out


def _patch_time(payload: bytes, t: float) -> bytes | None:
    """``payload`` with the float64 after the envelope key ``"t"`` replaced by ``t`` (or None)."""
    i = payload.find(b"\xa1t\xcb")
    if i < 0:
        return None
    return payload[: i + 3] + struct.pack(">d", t) + payload[i + 11 :]


def _flip(payload: bytes) -> bytes | None:
    """``payload`` with one bit of its middle flipped (an on-path change to a sealed payload)."""
    if len(payload) < 2:
        return None
    i = len(payload) // 2
    return payload[:i] + bytes([payload[i] ^ 0x01]) + payload[i + 1 :]


def cmd_compromised(a: argparse.Namespace) -> dict[str, Any]:
    """Replays, re-stamped copies of signed payloads and unsigned forgeries, on cmd and feedback."""
    import msgspec
    from bipedtele.link.messages import Command, encode

    att = Attacker(a)
    seen: dict[str, deque[tuple[float, bytes]]] = {"cmd": deque(maxlen=2000), "feedback": deque(maxlen=2000)}
    last_cmd: list[Any] = []
    sent: Counter[str] = Counter()

    def keep(name: str) -> Any:
        def cb(payload: bytes, t_recv: float) -> None:
            if payload in own:
                return
            seen[name].append((t_recv, payload))
            if name == "cmd":
                msg = _decode(payload)
                if isinstance(msg, Command):
                    last_cmd[:] = [msg]

        return cb

    own: set[bytes] = set()
    end = time.monotonic() + _bounded(a.seconds)
    # With two logins, the first (a leader's role) receives feedback and puts commands, the
    # second (a follower's role) receives commands and puts feedback.
    two = bool(a.user2)
    listen_via = {"cmd": "b" if two else "a", "feedback": "a"}
    put_via = {"cmd": "a", "feedback": "b" if two else "a"}
    with att.session():
        for name in seen:
            att.subscribe(att.key(name), keep(name), via=listen_via[name])
        n = 0
        while time.monotonic() < end and n < 10_000:
            time.sleep(1.0 / a.rate)
            n += 1
            now = time.time()
            for name, q in seen.items():
                old = [p for t, p in list(q) if now - t >= a.replay_after_s]
                if not old:
                    continue
                replay = old[n % len(old)]
                own.add(replay)
                att.put(att.key(name), replay, via=put_via[name])
                sent[f"replay_{name}"] += 1
                patched = _patch_time(old[-1], now) or _flip(old[-1])  # sealed: no time to find, a bit flipped
                if patched is not None:
                    own.add(patched)
                    att.put(att.key(name), patched, via=put_via[name])
                    sent[f"restamped_{name}"] += 1
            # the leader's last command, or (sealed: none readable) one with a guessed sid
            real = last_cmd[0] if last_cmd else Command(sid=att.sid, seq=n, t=now)
            forged = encode(msgspec.structs.replace(real, seq=real.seq + 1, t=now, ref=[a.forward, a.turn]))
            own.add(forged)
            att.put(att.key("cmd"), forged)
            sent["unsigned_cmd"] += 1
            if len(own) > 50_000:
                own.clear()
    att.out["sent"] = dict(sent)
    return att.out


ATTACKS = {
    "commands": cmd_commands,
    "poison": cmd_poison,
    "future": cmd_future,
    "stream": cmd_stream,
    "clock-forge": cmd_clock_forge,
    "flood": cmd_flood,
    "compromised": cmd_compromised,
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("attack", choices=sorted(ATTACKS))
    ap.add_argument("--connect", required=True)
    ap.add_argument("--robot-id", default="nao1")
    ap.add_argument("--user", default="")
    ap.add_argument("--password", default="")
    ap.add_argument("--user2", default="", help="a second login (compromised: the follower's role)")
    ap.add_argument("--password2", default="")
    ap.add_argument("--timeout", type=float, default=5.0, help="session open timeout [s]")
    ap.add_argument("--seconds", type=float, default=2.0, help="how long (per key for `commands`)")
    ap.add_argument("--rate", type=float, default=50.0, help="messages (rounds) per second")
    ap.add_argument("--keys", default="{root}/cmd", help="commands: comma-separated key expressions")
    ap.add_argument("--sids", type=int, default=1, help="commands: alternate among this many session ids")
    ap.add_argument("--forward", type=float, default=6.0, help="forward speed asked [cm/s]")
    ap.add_argument("--turn", type=float, default=0.0, help="turn speed asked [deg/s]")
    ap.add_argument("--targets", default="cmd,feedback", help="future: cmd, feedback or both")
    ap.add_argument("--ahead", type=float, default=1.0, help="future: stamp this far ahead [s]")
    ap.add_argument("--gap", type=float, default=1.0, help="future: seconds between two targets")
    ap.add_argument("--kind", choices=["cmd", "feedback"], default="cmd", help="stream: which side to play")
    ap.add_argument("--shift", type=float, default=0.1, help="stream: clock shift [s]")
    ap.add_argument("--as", dest="as_", choices=["own", "peer"], default="own", help="clock-forge: responder sid")
    ap.add_argument("--offset", type=float, default=5.0, help="clock-forge: forged clock offset [s]")
    ap.add_argument("--back-s", type=float, default=0.0, help="clock-forge: delay of answers to the leader [s]")
    ap.add_argument("--shave-s", type=float, default=0.004, help="clock-forge: round trip left [s]")
    ap.add_argument("--pingers", default="", help="clock-forge: LEADER_SID,FOLLOWER_SID known beforehand")
    ap.add_argument("--replay-after-s", type=float, default=0.5, help="compromised: replay payloads this old [s]")
    a = ap.parse_args(argv)
    if not 0 < a.rate <= 20_000 or not math.isfinite(a.rate):
        ap.error("--rate: allowed: 0 < rate <= 20000")
    _bounded(a.seconds)
    out = ATTACKS[a.attack](a)
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
