"""The node runtime's one fast-mode loop (issue 22): both programs' ``--realtime off`` runs use it."""

from __future__ import annotations

import inspect
import threading

import pytest
from bipedtele.config.profile import load_config
from bipedtele.link.node import Node, StepClock

pytestmark = pytest.mark.timeout(60)


def test_run_stepped_steps_the_clock_until_the_step_says_stop() -> None:
    node = Node(load_config("default"), "follower", takeover_after_s=0.5)
    clock = StepClock(0.01, t0=100.0)
    seen: list[float] = []

    def step(t: float) -> bool:
        seen.append(t)
        return len(seen) < 5

    assert node.run_stepped(clock, step) == 5
    assert seen == pytest.approx([100.0, 100.01, 100.02, 100.03, 100.04])
    assert clock.ticks == 4  # the last period ended the run: the clock stays on it


def test_run_stepped_ends_when_a_stop_is_asked_for() -> None:
    node = Node(load_config("default"), "leader", takeover_after_s=0.5)
    node._stop = threading.Event()  # what entering the node sets up (SIGINT/SIGTERM set it)
    calls: list[float] = []

    def step(t: float) -> bool:
        calls.append(t)
        if len(calls) == 3:
            node.stop.set()
        return True

    assert node.run_stepped(StepClock(0.001, t0=0.0), step) == 3


def test_both_programs_run_fast_mode_through_the_node() -> None:
    from bipedtele.follower.app import FollowerApp
    from bipedtele.leader.app import LeaderApp

    assert "run_stepped" in inspect.getsource(FollowerApp._run_fast)
    assert "run_stepped" in inspect.getsource(LeaderApp._run_loop)
