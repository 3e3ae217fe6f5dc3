"""The walker's turn limit-cycle onset and command latency (bipedtele.follower.sim.turn_onset)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("pybullet")

from bipedtele.follower.sim.turn_onset import (
    OnsetSettings,
    constant_run,
    oscillation_period,
    step_latency,
    step_means,
)


@pytest.mark.timeout(30)
def test_oscillation_period_of_a_sine() -> None:
    dt = 0.02
    t = np.arange(0.0, 8.0, dt)
    assert oscillation_period(3.0 + np.sin(2 * math.pi * t / 1.2 + 0.3), dt) == pytest.approx(1.2, rel=1e-3)
    assert math.isnan(oscillation_period(np.ones(50), dt))


@pytest.mark.timeout(30)
def test_step_means_groups_runs() -> None:
    turn = np.array([1.0, 3.0, 10.0, 20.0, 30.0, -1.0])
    starts = np.array([0.0, 0.0, 0.4, 0.4, 0.4, 0.8])
    assert step_means(turn, starts) == pytest.approx([2.0, 20.0, -1.0])


@pytest.mark.compute
@pytest.mark.timeout(120)
def test_walker_limit_cycle_above_and_not_below() -> None:
    """T = 1.2 s: no limit cycle at tau = 1, a limit cycle of period T at tau = 3 (20 s warm-up)."""
    st = OnsetSettings(warmup_s=20.0, cycles=4)
    low = constant_run(1.0, 1.2, st)
    high = constant_run(3.0, 1.2, st)
    assert not low.limit_cycle and low.turn_std < 1.0
    assert high.limit_cycle and high.turn_std > 20.0
    assert high.period_s == pytest.approx(1.2, rel=0.02)


@pytest.mark.compute
@pytest.mark.timeout(120)
def test_latency_is_the_wait_for_the_next_step() -> None:
    """A turn step waits for the next step boundary: about 0 s at a boundary, h - 0.2 s 0.2 s later."""
    out = step_latency(0.8, stride=10, settle_s=4.0, after_cycles=2)
    assert out["phase_s"] == pytest.approx([0.0, 0.2])
    assert out["latency_s"][0] == pytest.approx(0.0, abs=0.03)
    assert out["latency_s"][1] == pytest.approx(0.2, abs=0.03)
