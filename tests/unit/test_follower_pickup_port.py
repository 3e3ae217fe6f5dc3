"""A command picked up between ticks re-runs the period from the state kept before it, the port's energy included.

With a scheme that counts its port's energy (``tdpa``), a period re-run by
:meth:`~bipedtele.follower.loop.FollowerLoop.pickup` counts the period once, with the
picked-up command, exactly as a tick that had the command first: the energy the first run of
the period counted is not kept.
"""

from __future__ import annotations

import numpy as np
import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.loop import FollowerLoop, command_inbox
from bipedtele.link.messages import Command
from fakes.kinematic_robot import KinematicRobot


class _Twin:
    """A follower loop with the tdpa scheme, driven in simulated time by scripted commands."""

    def __init__(self) -> None:
        cfg = load_config("default", ["control.scheme=tdpa"])
        self.t, self.seq = 1000.0, 0
        self.sent: list[tuple[float, Command]] = []
        self.robot = KinematicRobot()
        self.robot.connect()
        self.taken: Command | None = None
        self.loop = FollowerLoop(
            self.robot,
            cfg.section("control"),
            cfg.section("follower"),
            command_inbox(cfg.section("follower"), source=self.latest),
            lambda msg: None,
            now=lambda: self.t,
        )

    def latest(self) -> tuple[Command, float] | None:
        arrived = [(ta, c) for ta, c in self.sent if ta <= self.t]
        if not arrived or arrived[-1][1] is self.taken:
            return None
        self.taken = arrived[-1][1]
        return arrived[-1][1], arrived[-1][0]

    def command(self, v: float, w: float) -> None:
        self.seq += 1
        energy = [0.01 * self.seq, 0.02 * self.seq]  # the leader port's input energy [N cm]
        self.sent.append((self.t, Command(sid=7, seq=self.seq, t=self.t, ref=[v, w], h2_s=0.1, energy=energy)))

    def run(self, seconds: float) -> None:
        for _ in range(round(seconds / self.loop.dt)):
            self.command(5.0 + np.sin(self.t), 2.0)
            self.loop.tick()
            self.robot.advance(self.loop.dt)
            self.t += self.loop.dt


@pytest.mark.timeout(60)
def test_a_picked_up_period_counts_the_port_energy_once() -> None:
    early, late = _Twin(), _Twin()
    early.run(2.0)
    late.run(2.0)
    early.command(1.0, -3.0)  # arrived just before the tick
    early.loop.tick()
    late.loop.tick()  # the tick ran without it; it arrives 7 ms later and is picked up
    late.t += 0.007
    late.command(1.0, -3.0)
    assert late.loop.pickup() is True
    e_in, e_out = late.loop.port.state.e_in, late.loop.port.state.e_out
    assert np.any(e_in + e_out > 0.0)  # the port counted something
    np.testing.assert_allclose(e_in, early.loop.port.state.e_in, rtol=0, atol=1e-12)
    np.testing.assert_allclose(e_out, early.loop.port.state.e_out, rtol=0, atol=1e-12)
