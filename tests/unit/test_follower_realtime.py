"""Real-time stepping of the follower (follower/realtime.py) on a fake clock."""

from __future__ import annotations

import threading

import pytest
from bipedtele.follower.realtime import RealtimeStepper
from bipedtele.pacer import Pacer

pytestmark = pytest.mark.timeout(30)

STEP = 1.0 / 240.0  # the sim NAO's physics step [s]


class FakeClock:
    """Time moves when the pacer sleeps and when a step 'works'."""

    def __init__(self) -> None:
        self.t = 50.0

    def __call__(self) -> float:
        return self.t

    def sleep(self, timeout_s: float, wake: threading.Event) -> bool:
        if wake.is_set():
            return True
        self.t += timeout_s if timeout_s > 0 else 1e-6
        return False


def _run(step_cost, seconds: float, max_lag_s: float = 0.25) -> tuple[RealtimeStepper, float, int]:
    clk = FakeClock()
    pacer = Pacer(STEP, clock=clk, sleep=clk.sleep)
    stepper = RealtimeStepper(pacer, steps_per_tick=5, max_lag_s=max_lag_s)
    t0 = clk.t
    ticks = [0]

    def advance() -> None:
        clk.t += step_cost(stepper.steps)

    def tick() -> None:
        ticks[0] += 1

    stepper.run(tick, advance, lambda: None, lambda: clk.t - t0 >= seconds)
    return stepper, clk.t - t0, ticks[0]


def test_robot_time_keeps_up_with_the_wall_clock_when_frames_overrun_steps() -> None:
    """Two 10 ms camera renders every 0.1 s inside 4.2 ms physics steps: the pacer skips the
    deadlines that passed, and the robot takes those steps at once (before the fix it lost
    one step per skipped deadline and walked at 0.78 of real time in the demo)."""

    def cost(n: int) -> float:
        return 0.010 if n % 12 == 0 else 0.0005  # a render every 12 steps (2 cameras, 10 fps)

    stepper, grid_time, ticks = _run(cost, 20.0)  # time on the fake clock, not wall-clock speed
    robot_time = stepper.steps * STEP
    assert robot_time == pytest.approx(grid_time, abs=3 * STEP), (robot_time, grid_time)
    assert stepper.caught_up_steps > 0 and stepper.dropped_steps == 0
    assert ticks == pytest.approx(stepper.steps / 5, abs=1)  # a control tick every 5 steps


def test_without_overruns_every_step_waits_for_its_deadline() -> None:
    stepper, grid_time, _ = _run(lambda n: 0.0005, 5.0)
    assert stepper.steps * STEP == pytest.approx(grid_time, abs=2 * STEP)
    assert stepper.caught_up_steps == 0 and stepper.dropped_steps == 0


def test_a_robot_slower_than_real_time_gives_up_the_lag_beyond_the_bound() -> None:
    """Every step costs twice its own time: the stepper never waits, keeps at most
    ``max_lag_s`` of lag, and counts the steps it gave up."""
    stepper, grid_time, _ = _run(lambda n: 2 * STEP, 10.0, max_lag_s=0.25)
    assert stepper.dropped_steps > 0
    lag = grid_time - stepper.steps * STEP - stepper.dropped_steps * STEP
    assert lag <= 0.25 + 2 * STEP
    assert stepper.steps * STEP == pytest.approx(grid_time / 2, rel=0.01)


def test_steps_per_tick_must_be_positive() -> None:
    clk = FakeClock()
    with pytest.raises(ValueError, match="steps_per_tick"):
        RealtimeStepper(Pacer(STEP, clock=clk, sleep=clk.sleep), 0)
