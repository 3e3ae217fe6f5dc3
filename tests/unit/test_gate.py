"""SequenceGate: stale/duplicate rejection, bound to one sender session, seq-jump bound."""

from __future__ import annotations

import threading

import pytest
from bipedtele.link.gate import FollowedSessionGate, SequenceGate
from bipedtele.link.messages import MAX_SEQ, Command


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def m(sid: int, seq: int) -> Command:
    return Command(sid=sid, seq=seq, t=1.0)


def test_in_order_accepted_old_rejected() -> None:
    g = SequenceGate()
    assert g.accept(m(7, 1)) is None
    assert g.accept(m(7, 2)) is None
    assert g.accept(m(7, 5)) is None  # gaps are fine (lost messages)
    assert g.accept(m(7, 5)) == "duplicate"
    assert g.accept(m(7, 3)) == "stale"
    assert g.accept(m(7, 6)) is None
    assert g.last == (7, 6)
    assert g.bound_sid == 7


def test_new_sid_takes_over_only_after_silence() -> None:
    """Adapted from the old ``test_new_sid_resets``: a new sid used to reset the gate at
    once (the defect: any sender could interleave); now it waits for the bound session's
    silence, which a restarted peer's old session shows."""
    clk = FakeClock()
    g = SequenceGate(takeover_after_s=0.5, clock=clk)
    assert g.accept(m(1, 1000)) is None
    assert g.accept(m(2, 1)) == "foreign_session"
    clk.t += 0.4
    assert g.accept(m(2, 2)) == "foreign_session"
    clk.t += 0.2  # 0.6 s since sid 1's last accepted message
    assert g.accept(m(2, 3)) is None  # peer restarted, seq starts again
    assert g.bound_sid == 2
    assert g.accept(m(2, 3)) == "duplicate"
    assert g.accept(m(2, 4)) is None
    assert g.accept(m(1, 1001)) == "foreign_session"  # the old session is now the foreign one
    g.reset()
    assert g.last == (None, -1) and g.bound_sid is None
    assert g.accept(m(2, 1)) is None


def test_alternating_senders_do_not_all_pass() -> None:
    """Attack: two sessions interleave their messages; the old gate let all pass."""
    clk = FakeClock()
    g = SequenceGate(clock=clk)
    passed = {1: 0, 2: 0}
    reasons: dict[str, int] = {}
    for k in range(200):
        sid = 1 + k % 2
        clk.t += 0.01
        r = g.accept(m(sid, k + 1))
        if r is None:
            passed[sid] += 1
        else:
            reasons[r] = reasons.get(r, 0) + 1
    assert passed == {1: 100, 2: 0}
    assert reasons == {"foreign_session": 100}


def test_huge_seq_poison_is_dropped_and_the_leader_keeps_control() -> None:
    """Attack: one message with the leader's sid and seq = 2**63 - 1; the old gate accepted
    it and every later leader command (its enable=false included) was stale."""
    clk = FakeClock()
    g = SequenceGate(clock=clk)
    for seq in range(1, 11):
        clk.t += 0.01
        assert g.accept(m(7, seq)) is None
    clk.t += 0.001
    assert g.accept(m(7, MAX_SEQ)) == "seq_jump"
    clk.t += 0.009
    stop = Command(sid=7, seq=11, t=1.0, enable=False)
    assert g.accept(stop) is None
    assert g.last == (7, 11)


def test_seq_jump_bound_follows_elapsed_time() -> None:
    clk = FakeClock()
    g = SequenceGate(takeover_after_s=0.5, clock=clk, max_rate_hz=1000.0, seq_margin=10)
    assert g.accept(m(3, 100)) is None
    clk.t += 0.125  # at most 0.125 * 1000 + 10 = 135 newer (binary-exact times)
    assert g.accept(m(3, 236)) == "seq_jump"
    assert g.accept(m(3, 235)) is None
    clk.t += 0.375  # a 0.375 s outage: up to 385 lost messages is plausible
    assert g.accept(m(3, 620)) is None
    # a rejected jump does not move the anchor
    assert g.accept(m(3, 620 + 10_000)) == "seq_jump"
    assert g.last == (3, 620)


def test_silent_bound_session_recovers_from_a_big_jump() -> None:
    """A sender faster than max_rate_hz (a tool running faster than real time) that lost a
    burst is followed again after takeover_after_s of silence, not locked out forever."""
    clk = FakeClock()
    g = SequenceGate(takeover_after_s=0.5, clock=clk, max_rate_hz=100.0, seq_margin=5)
    assert g.accept(m(4, 1)) is None
    seq = 1
    outcomes = []
    for _ in range(100):  # 10 kHz for 10 ms steps: far beyond 100 Hz
        clk.t += 0.01
        seq += 100
        outcomes.append(g.accept(m(4, seq)))
    assert outcomes[0] == "seq_jump"
    assert None in outcomes  # followed again
    first_ok = outcomes.index(None)
    assert 0.5 <= 0.01 * (first_ok + 1) <= 0.52
    assert g.accept(m(4, 2)) == "stale"  # replays stay dropped


def test_live_sid_follows_silence() -> None:
    clk = FakeClock()
    g = SequenceGate(takeover_after_s=0.5, clock=clk)
    assert g.live_sid is None
    assert g.accept(m(1, 1)) is None
    assert g.live_sid == 1
    clk.t += 0.5
    assert g.live_sid == 1
    clk.t += 0.01
    assert g.live_sid is None and g.bound_sid == 1
    assert g.accept(m(1, 2)) is None
    assert g.live_sid == 1
    g.release()
    assert g.live_sid is None and g.bound_sid == 1


def test_release_lets_another_session_take_over_at_once() -> None:
    clk = FakeClock()
    g = SequenceGate(clock=clk)
    assert g.accept(m(1, 5)) is None
    assert g.accept(m(2, 1)) == "foreign_session"
    g.release()
    assert g.bound_sid == 1
    assert g.accept(m(2, 1)) is None
    assert g.bound_sid == 2
    assert g.accept(m(1, 6)) == "foreign_session"


def test_release_then_same_session_continues() -> None:
    clk = FakeClock()
    g = SequenceGate(clock=clk)
    assert g.accept(m(1, 5)) is None
    g.release()
    assert g.accept(m(1, 5)) == "duplicate"
    assert g.accept(m(1, 4)) == "stale"
    assert g.accept(m(1, 10**9)) is None


def test_bad_parameters() -> None:
    for kw in (
        {"takeover_after_s": 0.0},
        {"takeover_after_s": float("nan")},
        {"max_rate_hz": -1.0},
        {"seq_margin": -1},
    ):
        with pytest.raises(ValueError, match="allowed"):
            SequenceGate(**kw)  # type: ignore[arg-type]


def test_concurrent_senders_bind_exactly_one() -> None:
    g = SequenceGate()
    passed: dict[int, int] = {}
    lock = threading.Lock()

    def send(sid: int) -> None:
        for seq in range(1, 2001):
            if g.accept(m(sid, seq)) is None:
                with lock:
                    passed[sid] = passed.get(sid, 0) + 1

    threads = [threading.Thread(target=send, args=(sid,)) for sid in (1, 2, 3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10.0)
    assert len(passed) == 1
    ((sid, n),) = passed.items()
    assert g.bound_sid == sid and n == 2000


def test_the_followed_session_gate_takes_only_the_driving_session() -> None:
    """The follower's Status inbox: two leaders publish Status on the robot's key, alice
    drives (the command gate follows her), dave waits. Before, the Status gate bound to
    whichever spoke first after a 0.5 s silence (alice frozen 3 s: dave's, without a
    feedback age, for the rest of her drive) and dropped the driver's."""
    driving: list[int | None] = [None]
    g = FollowedSessionGate(lambda: driving[0])
    assert g.accept(m(1, 1)) == "foreign_session"  # nobody drives yet
    driving[0] = 1  # alice's commands taken
    assert g.accept(m(1, 2)) is None
    assert g.accept(m(2, 1)) == "foreign_session"  # dave waits: his Status says nothing of alice's path
    assert g.accept(m(1, 2)) == "duplicate" and g.accept(m(1, 1)) == "stale"
    driving[0] = 2  # the hand-over: dave's commands taken
    assert g.accept(m(1, 3)) == "foreign_session"
    assert g.accept(m(2, 2)) is None and g.accept(m(2, 3)) is None
    driving[0] = 1  # alice takes it back: her session again, newer than her last
    assert g.accept(m(1, 4)) is None
