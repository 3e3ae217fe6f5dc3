"""The released handle's stability margin (bipedtele.studies.margin, ``bipedtele margin``).

The bisection (simulated released handle, time-domain) is checked against the analytic
crossing of the characteristic equation on a loop where both are known: a fast equivalent
follower and a lightly damped handle (a finite critical delay), and the same loop with more
damping, where the small-gain test says no constant delay destabilises it.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.studies.margin import (
    DelayProcess,
    LoopParams,
    critical_delay,
    critical_scale,
    small_gain_holds,
)

pytestmark = [pytest.mark.compute, pytest.mark.timeout(180)]

#: A loop with a finite critical delay: the follower's model answers within ~20 ms.
FAST = LoopParams(m=0.15, k_m=0.4, k_g=160.0, D=0.01, k_s=1.0, beta_e=0.01, sigma_e=0.0, alpha=1.0)


def test_bisection_finds_the_analytic_critical_delay() -> None:
    h_c = critical_delay(FAST)
    assert not small_gain_holds(FAST) and 0.05 < h_c < 0.2  # 0.114 s
    found = critical_scale(
        [FAST], [DelayProcess(0.1)], None, ControlConfig(), hi=0.4, iters=10, duration_s=6.0, dt=0.0005
    )
    assert found[0] == pytest.approx(h_c, rel=0.03), (found, h_c)


def test_where_the_small_gain_test_holds_no_delay_destabilises() -> None:
    damped = replace(FAST, alpha=20.0)
    assert small_gain_holds(damped) and critical_delay(damped) == math.inf
    found = critical_scale(
        [damped], [DelayProcess(0.1)], None, ControlConfig(), hi=0.4, iters=4, duration_s=6.0, dt=0.0005
    )
    assert found[0] == math.inf
    # the comparison's own loop (floor damping, both channels): stable for every constant delay
    cfg = ControlConfig()
    for ch in (0, 1):
        p = LoopParams.from_config(cfg, ch, 0.15, cfg.s_e_min, cfg.alpha_m_min)
        assert small_gain_holds(p) and critical_delay(p) == math.inf


def test_the_command_writes_the_map_and_refuses_a_bad_grid() -> None:
    cli = [sys.executable, "-m", "bipedtele.cli", "margin"]
    r = subprocess.run(
        [*cli, "--means", "0,1", "--alphas", "0.05,1", "--iters", "2", "--hi", "2", "--duration", "4", "--json", "-"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["means_s"] == [0.0, 1.0] and data["rules"] == ["floor", "ratio", "scheduled", "worst-case"]
    fwd = data["channels"][0]
    assert fwd["name"] == "forward" and fwd["alpha_40"][1] == pytest.approx(0.4 * 160.0 * 0.625)
    assert set(fwd["decay_per_s"]) == set(data["variants"]) and len(fwd["decay_per_s"]["constant"]) == 2
    assert all(set(by) == set(data["variants"]) for by in fwd["critical_mean_delay_s"].values())
    bad = subprocess.run([*cli, "--means", "0,x"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--means" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
