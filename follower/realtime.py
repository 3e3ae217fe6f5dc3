"""Real-time stepping of the follower: the robot's time follows the wall clock.

Between two control ticks the robot's time moves on one physics step per deadline of a
:class:`~bipedtele.pacer.Pacer` grid, and a command that arrives while waiting is applied
before the next step. When a step overruns (a camera frame rendered inside it, a slow
scheduler), the pacer skips the deadlines that passed; the robot then takes the missed
steps at once, so its time keeps up with the wall clock instead of losing one step per
skipped deadline (a simulated NAO rendering two cameras fell to 0.78 of real time, which a
real robot never does). A lag beyond ``max_lag_s`` is given up (counted in
:attr:`RealtimeStepper.dropped_steps`): a robot that cannot run in real time does not then
run flat out forever.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from bipedtele.pacer import Pacer

__all__ = ["RealtimeStepper"]


class RealtimeStepper:
    """Drive ticks and physics steps on a pacer's grid.

    Parameters
    ----------
    pacer : Pacer
        Grid of one physics step (``period_s`` = the step [s]).
    steps_per_tick : int
        Physics steps per control tick.
    max_lag_s : float
        Largest lag of the robot's time behind the grid that is caught up [s].
    """

    def __init__(self, pacer: Pacer, steps_per_tick: int, max_lag_s: float = 0.25) -> None:
        if steps_per_tick < 1:
            raise ValueError(f"steps_per_tick = {steps_per_tick}: allowed: an integer >= 1")
        self.pacer = pacer
        self.steps_per_tick = int(steps_per_tick)
        self.max_lag_steps = max(1, math.floor(max_lag_s / pacer.period_s))
        self.steps = 0
        self.ticks = 0
        self.caught_up_steps = 0
        self.dropped_steps = 0

    def run(
        self,
        tick: Callable[[], None],
        advance: Callable[[], None],
        pickup: Callable[[], None],
        stopping: Callable[[], bool],
    ) -> None:
        """Run until ``stopping()``: a tick, ``steps_per_tick`` steps on the grid, again.

        Parameters
        ----------
        tick : callable
            One control tick.
        advance : callable
            One physics step of the robot.
        pickup : callable
            Called when a wait is cut short (a command arrived, :meth:`Pacer.notify`).
        stopping : callable
            True when the run must end (checked at every tick and wait).
        """
        pacer = self.pacer
        base = 0  # grid deadlines that belong to no step (lag given up)
        while not stopping():
            tick()
            self.ticks += 1
            for _ in range(self.steps_per_tick):
                advance()
                self.steps += 1
                lag = pacer.passed() - base - self.steps
                if lag >= 0:  # this step's deadline passed while stepping: no wait, next step now
                    if lag > self.max_lag_steps:
                        self.dropped_steps += lag - self.max_lag_steps
                        base += lag - self.max_lag_steps
                    else:
                        self.caught_up_steps += 1
                    continue
                while pacer.k - base < self.steps and not stopping():
                    if not pacer.wait():
                        pickup()
                if stopping():
                    return
