"""The real loops' ports and the comparison's many-run wiring give the same outputs, for every scheme.

``LeaderPort`` / ``FollowerPort`` (one run, shape ``(2,)``) against the same scheme methods
called on all runs at once as :mod:`bipedtele.studies.compare` calls them (shape ``(n,
2)``, one :class:`EnergyCounter` for the runs, counted by the scheme as the loops count it), over a seeded sequence of messages:
the speed the handle follows, the robot's command, and every field the next messages carry
agree to 1e-12 on every period.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.online import OnlineChooser
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes import scheme_class, scheme_names
from bipedtele.control.schemes.paper import Paper
from bipedtele.control.schemes.ports import EnergyCounter
from bipedtele.control.schemes.runtime import FollowerPort, LeaderPort
from bipedtele.studies.compare_kernel import regime_inputs, simulate
from bipedtele.studies.regimes import REGIMES, CompareParams

CFG = ControlConfig()
K_M = np.asarray(CFG.k_m, dtype=float)
RUNS, PERIODS, DT = 5, 60, 0.01


def _close(a: object, b: object) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return bool(np.allclose(np.asarray(a, dtype=float), np.asarray(b, dtype=float), rtol=1e-12, atol=1e-12))


@pytest.mark.timeout(30)
@pytest.mark.parametrize("name", scheme_names())
def test_the_leader_port_is_the_many_run_law_run_by_run(name: str) -> None:
    scheme = scheme_class(name)(CFG)
    rng = np.random.default_rng(1)
    ports = [LeaderPort(scheme, K_M) for _ in range(RUNS)]
    many = EnergyCounter((RUNS, 2))
    for k in range(PERIODS):
        r, z_e, eta, wave = (rng.normal(0.0, 5.0, (RUNS, 2)) for _ in range(4))
        energy = np.full((RUNS, 2), 0.02 * k)
        t_sent, t_recv = 0.02 * k, 0.02 * k * 1.25 + 0.3  # the delay grows: gain below one
        follow = [
            p.felt_speed(r[i], z_e[i], eta[i], wave[i], energy[i], t_sent, t_recv, DT) for i, p in enumerate(ports)
        ]
        gain = ports[0].wave_gain.gain
        signal = np.stack([scheme.read_feedback(z_e[i], eta[i], wave[i]) for i in range(RUNS)])
        law = scheme.leader_force(r, signal, gain, K_M)
        law = scheme.limit_leader(law, r, many, energy, K_M, DT)
        scheme.count_leader(many, law, r, energy, DT)
        assert _close(np.stack(follow), law.followed(r, K_M)), f"period {k}"
        r_next = r + 0.1
        sent = [p.outgoing(r_next[i]) for i, p in enumerate(ports)]
        wave_many = scheme.command_wave(r_next, law, K_M)
        for i, (w, e) in enumerate(sent):
            assert _close(w, None if wave_many is None else wave_many[i]), f"period {k}: wave"
            assert _close(e, scheme.energy_sent(many.e_in[i])), f"period {k}: energy"


@pytest.mark.timeout(30)
@pytest.mark.parametrize("name", scheme_names())
def test_the_follower_port_is_the_many_run_law_run_by_run(name: str) -> None:
    scheme = scheme_class(name)(CFG)
    rng = np.random.default_rng(2)
    ports = [FollowerPort(scheme, K_M) for _ in range(RUNS)]
    many = EnergyCounter((RUNS, 2))
    for k in range(PERIODS):
        ref, eta, wave = (rng.normal(0.0, 5.0, (RUNS, 2)) for _ in range(3))
        energy = np.full((RUNS, 2), 0.05 * k)
        t_sent, t_recv = 0.02 * k, 0.02 * k * 1.25 + 0.3
        c_one = [p.command(ref[i], eta[i], wave[i], energy[i], t_sent, t_recv, DT) for i, p in enumerate(ports)]
        gain = ports[0].wave_gain.gain
        c = scheme.follower_command(ref, wave, gain, eta, K_M)
        c = scheme.limit_follower(c, eta, many, energy, K_M, DT)
        scheme.count_follower(many, c, eta, energy, K_M, DT)
        assert _close(np.stack(c_one), c), f"period {k}"
        for i, p in enumerate(ports):
            w, e = p.outgoing(eta[i])
            assert _close(w, scheme.feedback_wave(eta[i], K_M)), f"period {k}: wave"
            assert _close(e, scheme.energy_sent(many.e_in[i])), f"period {k}: energy"


class _AsksTwice(Paper):
    """The paper's law, asking the comparison for z_e twice per period."""

    def feedback_signal(self, z_e: Callable[[], np.ndarray], eta: np.ndarray, k_m: np.ndarray) -> np.ndarray:
        z_e()
        return z_e()


@pytest.mark.timeout(60)
def test_the_comparison_advances_the_equivalent_follower_once_per_period_however_often_asked() -> None:
    cp = CompareParams(study=StudyParams(duration_s=3.0))
    inp = regime_inputs(REGIMES[0], 3, 0, CFG, cp.study)
    chooser = OnlineChooser(CFG)
    once = simulate(Paper(CFG), inp, CFG, cp, chooser)
    twice = simulate(_AsksTwice(CFG), inp, CFG, cp, chooser)
    assert all(np.array_equal(once[m], twice[m]) for m in once)
    assert np.all(once["forward_error"] > 0.0)  # the runs moved
