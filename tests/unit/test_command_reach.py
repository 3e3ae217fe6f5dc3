"""CommandReach: the leader tells whether the follower applies its commands (cmd_seq)."""

from __future__ import annotations

import logging

import pytest
from bipedtele.leader.reach import LOST, REFUSED, STALLED, CommandReach
from bipedtele.link.messages import Feedback

FOLLOWER = 77


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def run(
    reach: CommandReach, clock: Clock, sent: list[int], seconds: float, fb: dict | None, present: bool = True
) -> None:
    """``seconds`` of a leader at 100 Hz commands, 50 Hz feedback built from ``fb``
    (``cmd_seq`` a callable of our last seq), the side thread checking at 20 Hz."""
    for k in range(round(seconds * 100)):
        clock.t += 0.01
        sent[0] += 1
        if fb is not None and k % 2 == 0:
            fields = dict(fb)
            fields["cmd_seq"] = fields["cmd_seq"](sent[0])
            reach.on_feedback(Feedback(sid=FOLLOWER, seq=k + 1, **fields))
        if k % 5 == 0:
            reach.check(present)


def make() -> tuple[CommandReach, Clock, list[int]]:
    clock, sent = Clock(), [0]
    return CommandReach(lambda: sent[0], window_s=1.5, clock=clock), clock, sent


def warnings(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_acknowledged_commands_give_no_warning(caplog: pytest.LogCaptureFixture) -> None:
    reach, clock, sent = make()
    # The follower applies our commands with a 0.2 s round trip.
    run(reach, clock, sent, 10.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    assert reach.ever_reached and not reach.never_reached and warnings(caplog) == []


def test_refused_commands_are_told_within_2_s_once(caplog: pytest.LogCaptureFixture) -> None:
    reach, clock, sent = make()
    t0 = clock.t
    # Feedback arrives (the router forwards it) but the follower applies none of ours.
    for _ in range(50):
        run(reach, clock, sent, 0.1, {"cmd_seq": lambda s: 0, "state": "standing"})
        if warnings(caplog):
            break
    assert clock.t - t0 <= 2.0
    run(reach, clock, sent, 8.0, {"cmd_seq": lambda s: 0, "state": "standing"})
    (line,) = warnings(caplog)  # one line, not one per check
    assert line.startswith("commands not reaching the robot: refused by the router's ACL?")
    assert reach.never_reached and reach.warnings == 1


def test_no_feedback_while_the_follower_is_heard_is_told_as_refused(caplog: pytest.LogCaptureFixture) -> None:
    # A leader logged in as the follower's user: the router forwards the follower's
    # status (2 Hz) to it, never its feedback, and drops its commands.
    reach, clock, sent = make()
    for _ in range(30):
        run(reach, clock, sent, 0.1, None)
        reach.on_heard()  # a status of the follower every 0.1 s here
    (line,) = warnings(caplog)
    assert line.startswith(REFUSED) and "no feedback arrives" in line
    assert reach.never_reached and reach.never_acknowledged


def test_nothing_heard_while_present_is_a_lost_link_not_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    # Presence lingers but nothing at all arrives from the start (a path that never
    # carried anything): the router's ACL is not blamed.
    reach, clock, sent = make()
    run(reach, clock, sent, 3.0, None)
    (line,) = warnings(caplog)
    assert line.startswith(LOST) and "ACL" not in line
    assert not reach.never_reached and reach.never_acknowledged


def test_a_stalled_link_is_told_as_lost_not_as_refused(caplog: pytest.LogCaptureFixture) -> None:
    """Issue 19: commands got through, then the path stalled (no feedback, no status) while
    the follower's presence was still seen; the leader blamed the router's ACL."""
    reach, clock, sent = make()
    run(reach, clock, sent, 5.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    t_stall = clock.t
    run(reach, clock, sent, 4.0, None)  # the stall: nothing arrives, presence still seen
    (line,) = warnings(caplog)
    assert "ACL" not in line and "refused" not in line
    assert line.startswith("link lost: no feedback for") and "(path or router down?)" in line
    silent = float(line.removeprefix("link lost: no feedback for").split(" s")[0])
    assert 1.5 <= silent <= 2.0 and clock.t - t_stall >= silent
    assert reach.ever_reached and not reach.never_reached and not reach.never_acknowledged


def test_an_earlier_leaders_last_command_does_not_count() -> None:
    # The follower still shows seq 500 of a leader that left; ours pass 500 after 5 s.
    reach, clock, sent = make()
    run(reach, clock, sent, 8.0, {"cmd_seq": lambda s: 500, "state": "standing"})
    assert sent[0] > 500 and reach.never_reached


def test_no_follower_no_verdict(caplog: pytest.LogCaptureFixture) -> None:
    reach, clock, sent = make()
    run(reach, clock, sent, 5.0, None, present=False)
    assert not reach.exposed and not reach.never_reached and warnings(caplog) == []


def test_commands_that_get_through_again_are_told(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="bipedtele.leader")
    reach, clock, sent = make()
    run(reach, clock, sent, 3.0, {"cmd_seq": lambda s: 0, "state": "standing"})
    run(reach, clock, sent, 1.0, {"cmd_seq": lambda s: s - 10, "state": "walking"})
    assert len(warnings(caplog)) == 1 and reach.ever_reached and not reach.never_reached
    assert any("reach the robot again" in r.getMessage() for r in caplog.records)
    # A follower that does not fill cmd_seq acknowledges by walking.
    legacy, clock2, sent2 = make()
    run(legacy, clock2, sent2, 3.0, {"cmd_seq": lambda s: 0, "state": "walking"})
    assert legacy.ever_reached


def test_a_robot_never_present_is_told_once_naming_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    """Issue 23: an operator bound to another robot sees nothing of this one (the router's ACL
    hides its presence): after absent_s of commands, one line that names the robot, the user
    and the ACL's per-robot binding; none while the robot is there, none twice."""
    clock, sent = Clock(), [0]
    reach = CommandReach(lambda: sent[0], clock=clock, robot_id="nao2", user="alice", absent_s=10.0)
    run(reach, clock, sent, 9.5, None, present=False)
    assert warnings(caplog) == []
    run(reach, clock, sent, 1.0, None, present=False)
    (line,) = warnings(caplog)
    assert line.startswith("no robot nao2 on the router after 10 s") and "user 'alice'" in line
    assert "publishers_allowed 'user@robot_id'" in line
    run(reach, clock, sent, 30.0, None, present=False)
    assert len(warnings(caplog)) == 1 and reach.absent_warnings == 1
    # a robot that was present once and left is the lost case, not this one
    caplog.clear()
    clock2, sent2 = Clock(), [0]
    seen = CommandReach(lambda: sent2[0], clock=clock2, robot_id="nao1", absent_s=10.0)
    run(seen, clock2, sent2, 1.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    run(seen, clock2, sent2, 20.0, None, present=False)
    assert not [w for w in warnings(caplog) if w.startswith("no robot")] and seen.absent_warnings == 0


def test_a_robot_held_by_another_operator_is_told_as_held_not_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    """Issue 23, hand-over: bob's commands are refused because alice holds the robot (the
    follower's status says so, and its status is heard): the line names alice and the
    release, not the router's ACL; while bob has released the robot himself, no verdict."""
    clock, sent = Clock(), [0]
    holder: list[str | None] = ["alice"]
    released = [False]
    reach = CommandReach(
        lambda: sent[0],
        clock=clock,
        robot_id="nao1",
        user="bob",
        holder=lambda: holder[0],
        released=lambda: released[0],
    )
    for _ in range(40):  # 2 s of status heard, no feedback acknowledging bob
        reach.on_heard()
        run(reach, clock, sent, 0.05, None)
    (line,) = warnings(caplog)
    assert line.startswith("commands not reaching the robot: held by another operator: robot nao1 is held by alice")
    assert "ACL" not in line and not reach.never_reached and reach.held_warnings == 1
    # alice releases, bob takes: acknowledged again
    caplog.clear()
    holder[0] = "bob"
    run(reach, clock, sent, 1.0, {"cmd_seq": lambda s: s, "state": "walking"})
    assert warnings(caplog) == [] and reach.ever_reached
    # bob releases: his stops are not acknowledged by a robot that alice took again: no verdict
    released[0], holder[0] = True, "alice"
    for _ in range(60):
        reach.on_heard()
        run(reach, clock, sent, 0.05, None)
    assert warnings(caplog) == []


def test_a_gap_that_ends_with_the_followers_old_messages_is_a_stall_not_the_acl(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A cellular uplink's gap: commands flow on the free downlink, nothing arrives for 4 s,
    then the backlog: the follower's status and video sent during the gap arrive 4 s late
    (its feedback that old is refused before it reaches this check), and fresh feedback
    only after them. Before, "refused by the router's ACL?" was told at every gap's end."""
    caplog.set_level(logging.INFO, logger="bipedtele.leader")
    reach, clock, sent = make()
    acks = {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"}
    run(reach, clock, sent, 5.0, acks)
    run(reach, clock, sent, 4.0, None)  # the gap
    for _ in range(10):  # 1 s of the backlog: old status and video
        run(reach, clock, sent, 0.1, None)
        reach.on_heard(age_s=4.0)
    for _ in range(5):  # the first fresh messages of the drained path: a status, then feedback
        run(reach, clock, sent, 0.1, None)
        reach.on_heard(age_s=0.1)
    run(reach, clock, sent, 2.0, acks)
    lines = warnings(caplog)
    assert not any("ACL" in ln or "refused" in ln for ln in lines), lines
    assert [ln.split(" ")[0] for ln in lines] == ["link", "uplink"], lines
    assert lines[1].startswith(STALLED) and float(lines[1].removeprefix(STALLED).split(" s")[0]) >= 4.0
    assert reach.stall_warnings == 1 and not reach.never_reached
    assert any("reach the robot again" in r.getMessage() for r in caplog.records)


def test_old_messages_alone_never_name_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    """From the start only old messages arrive (a slow uplink's first queue): a stall is told."""
    reach, clock, sent = make()
    for _ in range(30):
        run(reach, clock, sent, 0.1, None)
        reach.on_heard(age_s=2.5)
    (line,) = warnings(caplog)
    assert line.startswith(STALLED) and not reach.never_reached and reach.never_acknowledged


def test_a_gap_right_after_a_fresh_frame_is_not_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    """The uplink stops: its last feedback, then a video frame 0.05 s later, then nothing.
    A window after the last feedback the frame is still within it: before, "heard, fresh,
    no acknowledgement for a window" named the router's ACL (emulated LTE row, 4 s gap)."""
    reach, clock, sent = make()
    run(reach, clock, sent, 5.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    run(reach, clock, sent, 0.05, None)
    reach.on_heard(age_s=0.05)  # the frame, fresh
    run(reach, clock, sent, 4.0, None)  # the gap
    lines = warnings(caplog)
    assert lines and not any("ACL" in ln or "refused" in ln for ln in lines), lines


def test_one_late_frame_in_a_near_zero_stretch_is_not_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    """A 3G uplink's near-zero stretch: the last feedback, then one video frame trickles in
    0.86 s later (0.85 s old, under the fresh bound), then nothing. Before, "heard, fresh,
    no acknowledgement for a window" named the router's ACL (emulated 3G row)."""
    reach, clock, sent = make()
    run(reach, clock, sent, 5.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    run(reach, clock, sent, 0.86, None)
    reach.on_heard(age_s=0.85)
    run(reach, clock, sent, 4.0, None)
    lines = warnings(caplog)
    assert lines and not any("ACL" in ln or "refused" in ln for ln in lines), lines


def test_two_messages_trickling_through_a_near_zero_stretch_are_not_the_acl(caplog: pytest.LogCaptureFixture) -> None:
    """A 3G uplink's near-zero stretch (one delivery a second): after the last feedback, a
    video frame trickles in 0.45 s old, then the follower's status 1.49 s after it, 0.05 s
    old, and the first feedback 0.55 s after that. Two fresh messages a window apart
    named the router's ACL (emulated 3G row, cameras at 30 frames/s); a refusal on a
    working path keeps the follower heard (its status at 2 Hz, its video), a third fresh
    message within the window."""
    reach, clock, sent = make()
    run(reach, clock, sent, 5.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    run(reach, clock, sent, 8.0, None)  # the near-zero stretch
    reach.on_heard(age_s=0.45)  # a frame trickles in
    run(reach, clock, sent, 1.49, None)
    reach.on_heard(age_s=0.05)  # the status
    run(reach, clock, sent, 0.55, None)
    run(reach, clock, sent, 1.0, {"cmd_seq": lambda s: max(0, s - 20), "state": "walking"})
    lines = warnings(caplog)
    assert lines and not any("ACL" in ln or "refused" in ln for ln in lines), lines
