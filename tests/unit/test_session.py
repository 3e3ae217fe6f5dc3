"""The session handshake (issue 20): HKDF, the state machine, session-keyed traffic."""

from __future__ import annotations

import struct

import pytest
from bipedtele.link.auth import SESSION_MAGIC, MacError, MessageAuth, hkdf_sha256
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import ZERO_NONCE, Command, Feedback, Hello, decode, encode
from bipedtele.link.session import Handshake, session_info

MASTER = MessageAuth(bytes(range(32)))
CMD = "bipedtele/nao1/cmd"
FB = "bipedtele/nao1/feedback"


def test_hkdf_rfc5869_test_case_1() -> None:
    okm = hkdf_sha256(
        bytes.fromhex("0b" * 22), bytes.fromhex("000102030405060708090a0b0c"), bytes.fromhex("f0f1f2f3f4f5f6f7f8f9"), 42
    )
    assert okm.hex() == ("3cb25f25faacd57a90434f64d0362f2a2d2d0a90cf1a5a4c5db02d56ecc4c5bf34007208d5b887185865")


def test_hkdf_rfc5869_test_case_3_empty_salt_and_info() -> None:
    okm = hkdf_sha256(bytes.fromhex("0b" * 22), b"", b"", 42)
    assert okm.hex() == ("8da4e775a563c18f715f802a063c5a31b8a11f5c5ee1879ec3454e5f3c738d2d9d201395faa4b61a96c8")


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _pair(clock: Clock, takeover: float = 0.5) -> tuple[Handshake, Handshake]:
    leader = Handshake("leader", 11, MASTER, takeover_after_s=takeover, clock=clock, wall=lambda: 1e9)
    follower = Handshake("follower", 22, MASTER, takeover_after_s=takeover, clock=clock, wall=lambda: 1e9)
    return leader, follower


def _exchange(a: Handshake, b: Handshake, rounds: int = 3) -> None:
    """Deliver every Hello due, both ways (a lossless, instant link)."""
    for _ in range(rounds):
        a._clock.t += 0.05  # type: ignore[attr-defined]
        for h in a.due():
            b.on_hello(decode(encode(h), Hello))  # type: ignore[arg-type]
        for h in b.due():
            a.on_hello(decode(encode(h), Hello))  # type: ignore[arg-type]


def _command(sid: int, seq: int) -> bytes:
    return encode(Command(sid=sid, seq=seq, t=1e9))


def _deliver(hs: Handshake, gate: SequenceGate, payload: bytes, topic: str = CMD) -> str | None:
    """The receiver's path: open under a session key, gate, mark accepted; return the drop reason."""
    try:
        body, s = hs.open(payload, topic)
    except MacError as exc:
        return exc.reason
    msg = decode(body)
    reason = gate.accept(msg)
    if reason is None:
        hs.accepted(s, msg.sid)
    return reason


def test_one_round_trip_completes_and_both_derive_the_same_key() -> None:
    clock = Clock()
    leader, follower = _pair(clock)
    assert leader.sign(b"x", CMD) is None and follower.sign(b"x", FB) is None  # nothing sent before
    hello = leader.due()
    assert len(hello) == 1 and hello[0].peer_nonce == ZERO_NONCE
    follower.on_hello(hello[0])
    answer = follower.due()
    assert [h.peer_nonce for h in answer] == [hello[0].nonce] and answer[0].peer_sid == 11
    leader.on_hello(answer[0])
    assert leader.complete and leader.peer_sid == 22  # one round trip
    signed = leader.sign(_command(11, 1), CMD)
    assert signed is not None and signed[:4] == SESSION_MAGIC
    # the follower binds when its gate accepts a command under the new key
    assert not follower.complete
    assert _deliver(follower, SequenceGate(), signed) is None
    assert follower.complete and follower.peer_sid == 11
    fb = follower.sign(b"\x80", FB)
    assert fb is not None and leader.open(fb, FB)[0] == b"\x80"
    # the key is HKDF(master, nL | nF, info | sidL | sidF)
    key = hkdf_sha256(bytes(range(32)), hello[0].nonce + answer[0].nonce, session_info(11, 22))
    assert MessageAuth(key, SESSION_MAGIC).verify(fb, FB) == b"\x80"


def test_a_replayed_old_hello_completes_nothing_and_its_traffic_is_old_session() -> None:
    clock = Clock()
    leader1, follower = _pair(clock)
    gate = SequenceGate(takeover_after_s=0.5, clock=clock)
    captured_hellos = leader1.due()
    follower.on_hello(captured_hellos[0])
    leader1.on_hello(follower.due()[0])
    captured = [leader1.sign(_command(11, n), CMD) for n in range(1, 4)]
    assert all(c is not None for c in captured)
    assert _deliver(follower, gate, captured[0]) is None  # leader 1 bound
    # leader 2 (a new process) binds after leader 1's silence
    leader2 = Handshake("leader", 33, MASTER, clock=clock, wall=lambda: 1e9)
    _exchange(leader2, follower)
    assert leader2.complete
    clock.t += 1.0
    assert _deliver(follower, gate, leader2.sign(_command(33, 1), CMD) or b"") is None
    assert follower.peer_sid == 33
    # leader 2 falls silent past the watchdog: leader 1's captured commands and Hello are replayed
    clock.t += 2.0
    follower.on_hello(captured_hellos[0])  # answered with a fresh follower nonce
    answers = follower.due()
    assert answers and all(h.nonce != ZERO_NONCE for h in answers)
    for c in captured[1:]:
        assert _deliver(follower, gate, c or b"") == "old_session"
    assert follower.peer_sid == 33 and gate.bound_sid == 33
    # a replayed old follower answer (echoing leader 1's nonce) completes nothing at leader 2
    old_answer = Hello(
        sid=22, seq=1, t=1e9, role="follower", nonce=bytes(32 * [7]), peer_sid=11, peer_nonce=captured_hellos[0].nonce
    )
    before = leader2.completed
    leader2.on_hello(old_answer)
    assert leader2.completed == before


def test_a_new_session_key_differs_even_with_the_same_follower() -> None:
    clock = Clock()
    keys = []
    follower = Handshake("follower", 22, MASTER, clock=clock)
    for sid in (11, 12):
        leader = Handshake("leader", sid, MASTER, clock=clock)
        _exchange(leader, follower)
        keys.append(leader.sign(b"\x80", CMD))
    assert keys[0] != keys[1]


def test_a_replayed_hello_of_the_bound_leader_gets_a_fresh_follower_nonce() -> None:
    clock = Clock()
    leader, follower = _pair(clock)
    hello = leader.due()[0]
    follower.on_hello(hello)
    first = follower.due()[0]
    leader.on_hello(first)
    gate = SequenceGate(takeover_after_s=0.5, clock=clock)
    assert _deliver(follower, gate, leader.sign(_command(11, 1), CMD) or b"") is None
    # the follower moves to leader 3 after leader 1's silence; then leader 1's first Hello is replayed
    leader3 = Handshake("leader", 33, MASTER, clock=clock)
    _exchange(leader3, follower)
    clock.t += 1.0
    assert _deliver(follower, gate, leader3.sign(_command(33, 1), CMD) or b"") is None
    assert follower.peer_sid == 33
    follower.on_hello(hello)
    again = [h for h in follower.due() if h.peer_sid == 11]
    assert again and again[0].nonce not in (first.nonce, ZERO_NONCE)


def test_master_signed_or_unsigned_commands_are_refused() -> None:
    clock = Clock()
    leader, follower = _pair(clock)
    _exchange(leader, follower)
    with pytest.raises(MacError) as exc:
        follower.open(MASTER.sign(_command(11, 1), CMD), CMD)
    assert exc.value.reason == "no_session"
    with pytest.raises(MacError) as exc:
        follower.open(_command(11, 1), CMD)
    assert exc.value.reason == "no_mac"
    other = MessageAuth(bytes(32)).derive(b"s", b"i")
    with pytest.raises(MacError) as exc:  # an earlier session's (another sid)
        follower.open(other.sign(_command(99, 1), CMD), CMD)
    assert exc.value.reason == "old_session"
    assert _deliver(follower, SequenceGate(), leader.sign(_command(11, 1), CMD) or b"") is None  # bound
    good = leader.sign(_command(11, 2), CMD) or b""
    altered = good[:-1] + bytes([good[-1] ^ 1])
    with pytest.raises(MacError) as exc:  # the bound session's, its tag altered on the way
        follower.open(altered, CMD)
    assert exc.value.reason == "bad_mac"
    for i in range(8, len(good) - 16):  # a byte of the nonce or of the sealed body altered
        altered = good[:i] + bytes([good[i] ^ 1]) + good[i + 1 :]
        with pytest.raises(MacError) as exc:
            follower.open(altered, CMD)
        assert exc.value.reason == "bad_mac", i
    assert struct.pack(">d", 1e9) not in good  # the send time is sealed: not readable on the way


def test_leader_binds_one_follower_and_rebinds_after_its_silence_with_a_new_nonce() -> None:
    clock = Clock()
    leader, f1 = _pair(clock, takeover=0.5)
    _exchange(leader, f1)
    assert _deliver(f1, SequenceGate(), leader.sign(_command(11, 1), CMD) or b"") is None  # f1 bound
    old = f1.sign(encode(Feedback(sid=22, seq=5, t=1e9)), FB)  # f1's traffic in this pairing
    assert old is not None
    n1 = leader.nonce
    assert leader.peer_sid == 22
    f2 = Handshake("follower", 44, MASTER, clock=clock)
    clock.t += 0.1
    _exchange(leader, f2)  # f2 answers while f1 is live: ignored
    assert leader.peer_sid == 22
    fb2 = f2.sign(b"\x80", FB)
    assert fb2 is None  # f2 has no session: sends nothing
    clock.t += 2.0  # f1 silent past the takeover
    for _ in range(4):
        clock.t += 0.3
        _exchange(leader, f2)
    assert leader.peer_sid == 44 and leader.nonce != n1
    with pytest.raises(MacError) as exc:  # the old pairing's traffic
        leader.open(old, FB)
    assert exc.value.reason == "old_session"


def test_hello_rates_fast_until_bound_then_slow() -> None:
    clock = Clock()
    leader, follower = _pair(clock)
    sent = 0
    for _ in range(40):  # 2 s without a follower
        sent += len(leader.due())
        clock.t += 0.05
    assert 7 <= sent <= 9  # about 4 Hz
    _exchange(leader, follower)
    sent = 0
    for _ in range(80):  # 4 s bound
        sent += len(leader.due())
        clock.t += 0.05
    assert 3 <= sent <= 5  # about 1 Hz


def test_replayed_hellos_do_not_evict_a_confirmed_candidate() -> None:
    clock = Clock()
    follower = Handshake("follower", 22, MASTER, clock=clock)
    leader = Handshake("leader", 11, MASTER, clock=clock)
    _exchange(leader, follower)  # the leader holds the key; the follower's candidate is confirmed
    for i in range(20):
        follower.on_hello(Hello(sid=1000 + i, seq=1, t=1e9, role="leader", nonce=bytes([i + 1]) * 32))
    assert _deliver(follower, SequenceGate(), leader.sign(_command(11, 1), CMD) or b"") is None


def _deliver_all(clock: Clock, parties: list[Handshake], rounds: int = 4) -> None:
    """Every Hello due goes to every other party (one shared clock key)."""
    for _ in range(rounds):
        clock.t += 0.05
        for a in parties:
            for h in a.due():
                for b in parties:
                    if b is not a:
                        b.on_hello(decode(encode(h), Hello))  # type: ignore[arg-type]


def test_a_second_leader_names_the_robots_feedback_to_the_first_other_leader_not_bad_mac() -> None:
    """Issue 23, hand-over: two operators of one robot share its key; the robot follows
    alice's session, and bob's leader, waiting for it, receives feedback under alice's
    session key. That is the robot's traffic to another leader (``other_leader``), not
    altered bytes (``bad_mac``, which the leader reports as keys that do not match); and
    the robot answers bob's clock pings (:meth:`Handshake.answers`)."""
    clock = Clock()
    alice, robot = _pair(clock)
    _exchange(alice, robot)
    signed = alice.sign(_command(11, 1), CMD)
    assert signed is not None and _deliver(robot, SequenceGate(), signed) is None and robot.peer_sid == 11
    bob = Handshake("leader", 33, MASTER, clock=clock, wall=lambda: 1e9)
    _deliver_all(clock, [alice, robot, bob])
    assert bob.complete and bob.peer_sid == 22  # the robot answered him: a candidate
    assert robot.answers(33) and robot.answers(11) and not robot.answers(44)
    clock.t += 1.1  # the robot's own Hello (1 Hz while bound) names alice's session
    _deliver_all(clock, [alice, robot, bob], rounds=1)
    fb = robot.sign(encode(Feedback(sid=22, seq=1, t=1e9)), FB)
    assert fb is not None
    with pytest.raises(MacError) as got:
        bob.open(fb, FB)
    assert got.value.reason == "other_leader"
    # without a Hello naming another leader lately, the same is a session key bob does not
    # hold (sealed: its sender's sid is not readable), never bad_mac (keys that do not match)
    clock.t += 10.0
    with pytest.raises(MacError) as got:
        bob.open(fb, FB)
    assert got.value.reason == "old_session"


def test_the_leaders_video_passes_only_the_bound_follower_session() -> None:
    """Issue 32, item 4: an earlier follower session's frames (replayed) never reach the screen."""
    from types import SimpleNamespace

    from bipedtele.link.messages import VideoFrame
    from bipedtele.link.session import LIVE_MAX_AGE_S, PeerBound, live_checks
    from bipedtele.link.transport import Keys

    hs = SimpleNamespace(peer_sid=None)
    node = SimpleNamespace(keys=Keys("nao1"), handshake=hs, role="leader")
    gate, age = live_checks(node, node.keys.video, SequenceGate(), None)
    assert isinstance(gate, PeerBound) and gate.strict and age == LIVE_MAX_AGE_S

    def frame(sid: int, seq: int) -> VideoFrame:
        return VideoFrame(sid=sid, seq=seq, t=1.0, camera="head", width=1, height=1, t_capture=1.0, jpeg=b"x")

    assert gate.accept(frame(5, 1)) == "no_session"  # before the handshake: nothing is live
    hs.peer_sid = 7
    assert gate.accept(frame(5, 2)) == "old_session"  # another (earlier) follower session
    assert gate.accept(frame(7, 1)) is None and gate.accept(frame(7, 1)) == "duplicate"
    status_gate, _ = live_checks(node, node.keys.status, SequenceGate(), None)
    assert isinstance(status_gate, PeerBound) and not status_gate.strict
    # the follower's receivers: the age bound only; commands and feedback: left as given
    follower = SimpleNamespace(keys=node.keys, handshake=hs, role="follower")
    cmd_gate = SequenceGate()
    assert live_checks(follower, node.keys.status, cmd_gate, None) == (cmd_gate, LIVE_MAX_AGE_S)
    assert live_checks(node, node.keys.cmd, cmd_gate, None) == (cmd_gate, None)


def test_the_leader_learns_its_follower_sessions_watch_epoch_from_the_handshake() -> None:
    """The follower's Hellos announce its watch epoch (sealed under the master key); the leader
    keeps the one of the follower session it binds, and a replayed Hello of an earlier
    follower session, with its own epoch, changes nothing."""
    clock = Clock()
    leader = Handshake("leader", 11, MASTER, clock=clock, wall=lambda: 1e9, watch_epoch=b"LEAD")
    follower = Handshake("follower", 22, MASTER, clock=clock, wall=lambda: 1e9, watch_epoch=b"FOL1")
    assert leader.peer_watch_epoch is None
    _exchange(leader, follower)
    assert leader.complete and leader.peer_watch_epoch == b"FOL1"
    old = Hello(
        sid=21,
        seq=9,
        t=1e9,
        role="follower",
        nonce=bytes(32 * [5]),
        peer_sid=11,
        peer_nonce=leader.nonce,
        watch=b"OLD!",
    )
    leader.on_hello(old)
    assert leader.peer_sid == 22 and leader.peer_watch_epoch == b"FOL1"
