"""A blind operator never drives (leader/blind.py): the loop in virtual time, the uplink stalled for 4 s.

The feedback source of tests/unit/test_leader_loop.py: feedback every 20 ms, 0.1 s on the
way; what is sent from 5 s to 9 s waits in the stalled uplink and arrives at 9.5 s. The
downlink is free: the loop's commands go out all the time.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.leader.operator import Hand
from bipedtele.leader.operators.pilot import DEFAULT_COURSE, PilotOperator
from test_leader_loop import T0, make_loop

pytestmark = pytest.mark.timeout(60)


def _stalled_h2(s: float) -> float:
    """Sent in [5 s, 9 s): waits until 9.5 s; else 0.1 s on the way."""
    return T0 + 9.5 - s if 5.0 <= s - T0 < 9.0 else 0.1


def _run(move_at: float | None, until: float = 14.0, overrides: tuple[str, ...] = ()):
    loop, sent, _ = make_loop(lambda s: np.zeros(2), _stalled_h2, overrides=list(overrides))
    hand = Hand(stiffness_n_m=300.0, tau_s=0.05)
    hand.set_target(np.array([0.02, 0.0]))  # pushing forward all along
    loop.device.set_operator(hand)
    for k in range(round(until / 0.001)):
        t = T0 + k * 0.001
        if move_at is not None and abs(t - (T0 + move_at)) < 0.0005:
            hand.set_target(np.array([0.03, 0.0]))  # the operator moves the handle
        loop.tick(now=t)
    return loop, [(c.t - T0, c.enable, c.ref) for c in sent]


def test_old_feedback_stops_the_robot_until_fresh_feedback_and_a_handle_move(caplog) -> None:
    """Before blind_stop_s the commands kept driving through the whole stall (the robot walked
    on for 12.4 s on a 3G trace while the operator saw "stale")."""
    with caplog.at_level(logging.INFO, logger="bipedtele.leader"):
        loop, cmds = _run(move_at=11.0)
    driving = [t for t, en, _ in cmds if 1.0 <= t < 6.4]
    assert driving and all(en for t, en, _ in cmds if 1.0 <= t < 6.4)
    # the newest feedback (sent at 4.98 s) passes 1.5 s at 6.48 s: the next command stops
    first_stop = next(t for t, en, _ in cmds if t > 1.0 and not en)
    assert 6.47 <= first_stop <= 6.5 + 0.011, first_stop
    stopped = [(en, ref) for t, en, ref in cmds if first_stop <= t < 11.0]
    assert all(not en and ref == [0.0, 0.0] for en, ref in stopped)  # fresh again at 9.5 s, no move yet
    resumed = next(t for t, en, _ in cmds if t >= 11.0 and en)
    assert resumed - 11.0 < 1.0, resumed
    assert loop.blind.stops == 1 and loop.blind.state == "seeing"
    assert "no fresh feedback for 1.5 s: the robot is stopped until it returns" in caplog.text


def test_without_a_handle_move_the_robot_stays_stopped() -> None:
    loop, cmds = _run(move_at=None)
    assert not any(en for t, en, _ in cmds if t >= 6.5)
    assert loop.blind.state == "rearm" and loop.sample is not None
    assert loop.sample.blind == "fresh feedback again: move the handle to walk on" and loop.sample.blind_stops == 1


def test_the_bound_is_the_configured_one_and_events_are_recorded() -> None:
    _loop, cmds = _run(move_at=None, until=7.0, overrides=("leader.blind_stop_s=0.5",))
    first_stop = next(t for t, en, _ in cmds if t > 1.0 and not en)
    assert 5.47 <= first_stop <= 5.5 + 0.011, first_stop
    from bipedtele.leader.blind import BlindGuard  # here: the other tests run on code without it too

    events: list[tuple[str, dict[str, float]]] = []
    guard = BlindGuard(1.0, 0.05, on_event=lambda name, data: events.append((name, data)), settle_s=0.5)
    x = np.zeros(2)
    assert not guard.check(0.0, False, None, x)  # nothing before the first feedback
    assert not guard.check(1.0, True, 0.9, x)
    assert (
        guard.check(2.0, True, 1.2, x)
        and guard.words() == "no fresh feedback for 1.2 s: the robot is stopped until it returns"
    )
    assert guard.check(3.0, True, 0.1, x)  # fresh: waits for a move
    assert guard.check(3.2, True, 0.1, x + 0.004)  # the force fades in and moves the handle: no move
    assert guard.check(3.6, True, 0.1, x + 0.0049)  # 0.9 mm from where it settled: under 2 % of 5 cm
    assert not guard.check(3.7, True, 0.1, x + 0.0051)
    assert [e for e, _ in events] == ["blind_stop", "blind_over"] and events[1][1]["stopped_s"] == pytest.approx(1.7)
    with pytest.raises(ValueError, match="blind_stop_s"):
        BlindGuard(0.0, 0.05)


def test_the_pilot_moves_its_handle_when_the_cockpit_asks_and_walks_on() -> None:
    """The scripted pilot reads the cockpit's line as a person would ("move the handle to
    walk on") and pushes its handle on. Before, its handle stayed where the course put it
    while the robot stood: on the 3G row of bench/internet.py the robot stood from its blind
    stop to the end of the run (1 pass of 5)."""
    cfg = load_config("default")
    pilot = PilotOperator(list(DEFAULT_COURSE), cfg.control.k_g, passes=10)
    loop, sent, _ = make_loop(lambda s: np.zeros(2), _stalled_h2, operator=pilot)
    for k in range(round(14.0 / 0.001)):
        loop.tick(now=T0 + k * 0.001)
    cmds = [(c.t - T0, c.enable) for c in sent]
    first_stop = next(t for t, en in cmds if t > 1.0 and not en)
    assert 6.47 <= first_stop <= 6.5 + 0.011, first_stop
    resumed = next((t for t, en in cmds if t >= 9.5 and en), None)  # fresh feedback again at 9.5 s
    assert resumed is not None and resumed - 9.5 < 2.0, resumed
    assert loop.blind.stops == 1 and loop.blind.state == "seeing"
    assert all(en for t, en in cmds if t > resumed + 0.1)


@pytest.mark.parametrize("push", [0.0, -1.0, float("nan")])
def test_a_bad_push_rate_is_named(push: float) -> None:
    with pytest.raises(ValueError, match="rearm_push_cm_s2"):
        PilotOperator(list(DEFAULT_COURSE), [1.0, 1.0], rearm_push_cm_s2=push)
