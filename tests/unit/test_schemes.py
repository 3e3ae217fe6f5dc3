"""The control schemes: the registry, a contract checker over every registered scheme, the port laws."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.schemes import Scheme, scheme_class, scheme_names
from bipedtele.control.schemes.base import LeaderLaw
from bipedtele.control.schemes.check import SchemeContractError, check_scheme
from bipedtele.control.schemes.paper import Paper
from bipedtele.control.schemes.ports import (
    EnergyCounter,
    follower_passivity,
    leader_passivity,
    wave_follower,
    wave_gain,
    wave_leader,
)
from bipedtele.control.schemes.tdpa import Tdpa

CFG = ControlConfig()
EXPECTED = {"paper", "paper-constant", "pd-worst-case", "pd-measured", "wave", "tdpa"}


def test_the_registry_holds_the_six_schemes_paper_first() -> None:
    names = scheme_names()
    assert set(names) >= EXPECTED
    assert names[0] == "paper"


def test_an_unknown_scheme_names_the_allowed_ones() -> None:
    with pytest.raises(ValueError, match=r"scheme 'nope': allowed: paper, .*tdpa"):
        scheme_class("nope")


@pytest.mark.timeout(30)
@pytest.mark.parametrize("name", scheme_names())
def test_every_registered_scheme_keeps_the_contract(name: str) -> None:
    check_scheme(name)  # damping, and every port law on (2,) and (n, 2), run by run as vectorised


class _RowsMix(Paper):
    """Broken on purpose: its leader force mixes the runs (each run feels the mean of all)."""

    name = "paper"

    def leader_force(
        self, r_m: np.ndarray, signal: np.ndarray, gain: float | np.floating, k_m: np.ndarray
    ) -> LeaderLaw:
        law = super().leader_force(r_m, signal, gain, k_m)
        mixed = np.broadcast_to(np.mean(np.atleast_2d(law.force), axis=0), law.force.shape)
        return LeaderLaw(mixed, r_m - mixed / k_m, law.received)


class _FollowsWrong(Paper):
    """Broken on purpose: the speed it says the handle follows is not the force's."""

    name = "paper"

    def leader_force(
        self, r_m: np.ndarray, signal: np.ndarray, gain: float | np.floating, k_m: np.ndarray
    ) -> LeaderLaw:
        law = super().leader_force(r_m, signal, gain, k_m)
        return LeaderLaw(law.force, law.followed(r_m, k_m) + 1.0, law.received)


class _ReadsTheOtherField(Paper):
    """Broken on purpose: sends z_e back in the comparison but reads eta from a real message."""

    name = "paper"

    def read_feedback(self, z_e: np.ndarray, eta: np.ndarray, wave: np.ndarray) -> np.ndarray:
        return eta


class _CountsTheMean(Tdpa):
    """Broken on purpose: its leader observer counts the mean power of all runs for each."""

    name = "tdpa"

    def count_leader(
        self, port: EnergyCounter, law: LeaderLaw, r_m: np.ndarray, other_in: np.ndarray, dt: float
    ) -> None:
        power = np.atleast_2d(law.force * r_m).mean(axis=0)
        port.add(np.broadcast_to(power, np.shape(r_m)), dt, other_in)


@pytest.mark.timeout(30)
@pytest.mark.parametrize(
    ("broken", "why"),
    [
        (_RowsMix, "run 0 alone differs"),
        (_FollowsWrong, "follow != r_m - F_m/k_m"),
        (_ReadsTheOtherField, "read_feedback"),
        (_CountsTheMean, "count_leader: run 0 alone counts e_in"),
    ],
)
def test_the_contract_checker_catches_a_broken_law(broken: type[Scheme], why: str) -> None:
    with pytest.raises(SchemeContractError, match=re.escape(why)):
        check_scheme(broken)


def test_worst_case_damping_is_the_papers_at_the_worst_delay() -> None:
    worst = scheme_class("pd-worst-case")(CFG, (0.6, 0.5))
    paper = scheme_class("paper")(CFG)
    a_w, s_w = worst.damping(np.zeros(3), np.zeros(3))
    a_p, s_p = paper.damping(np.full(3, 0.6), np.full(3, 0.5))
    assert np.allclose(a_w, a_p) and np.allclose(s_w, s_p)


def test_the_wave_channel_passes_a_steady_speed_unchanged() -> None:
    b = np.array([0.4, 0.4])
    r = np.array([5.0, -3.0])
    eta = r.copy()  # the robot walks at the commanded speed
    _, v_s = wave_follower(np.zeros(2), eta, b)
    f_m, u_m = wave_leader(r, v_s, b)
    r_s, _ = wave_follower(u_m, eta, b)
    assert np.allclose(r_s, r)
    assert np.allclose(f_m, 0.0)  # nothing to feel when the robot keeps up


def test_the_wave_gain_is_one_on_a_constant_delay_and_below_one_while_it_grows() -> None:
    steady = np.arange(100) - 20  # one new message per period
    assert np.allclose(wave_gain(steady, 10)[40:], 1.0)  # once messages flow (-1: none yet)
    growing = (np.arange(100) * 0.5).astype(int)  # messages arrive half as often: dh/dt = 0.5
    g = wave_gain(growing, 10)[20:]
    assert np.all(g < 0.8) and np.all(g > 0.6)


def test_the_passivity_controllers_never_give_out_more_than_came_in() -> None:
    rng = np.random.default_rng(3)
    dt = 0.01
    k_m = np.full(1000, 0.4)
    observer = rng.uniform(0.0, 0.05, 1000)
    r = rng.normal(0.0, 5.0, 1000)
    f = rng.normal(0.0, 3.0, 1000)
    f_pc = leader_passivity(f, r, observer, dt)
    assert np.all(f_pc * r * dt >= -observer - 1e-12)
    assert np.allclose(f_pc[f * r * dt >= -observer], f[f * r * dt >= -observer])  # untouched when passive
    eta = rng.normal(0.0, 5.0, 1000)
    c = follower_passivity(r, eta, observer, k_m, dt)
    assert np.all(k_m * (c - eta) * c * dt <= observer + 1e-9)
    passive = k_m * (r - eta) * r * dt <= observer
    assert np.allclose(c[passive], r[passive])


def test_the_energy_counter_tracks_the_observers_least_value() -> None:
    port = EnergyCounter((1,))
    port.add(np.array([2.0]), 1.0, np.array([0.0]))  # 2 in
    port.add(np.array([-3.0]), 1.0, np.array([1.0]))  # 3 out, the other side put in 1: observer -2
    assert port.e_in[0] == 2.0 and port.e_out[0] == 3.0
    assert port.min_observer[0] == -2.0


def test_the_running_wave_gain_is_one_at_a_steady_delay_and_falls_while_the_delay_grows() -> None:
    from bipedtele.control.schemes.runtime import WaveGain

    steady = WaveGain(0.5)
    for k in range(100):
        g = steady.update(k * 0.01, k * 0.01 + 0.3)
    assert g == pytest.approx(1.0)
    growing = WaveGain(0.5)
    for k in range(100):  # the delay grows 0.5 s per second: arrivals spread by 1.5
        g = growing.update(k * 0.01, k * 0.01 * 1.5 + 0.3)
    assert g == pytest.approx(math.sqrt(1 / 1.5), rel=1e-6)
    assert growing.update(0.5, 5.0) == g  # an older message says nothing about the rate


def test_the_follower_port_of_tdpa_gives_the_robot_no_energy_the_leader_did_not_put_in() -> None:
    from bipedtele.control.schemes.runtime import FollowerPort

    port = FollowerPort(scheme_class("tdpa")(CFG), np.asarray(CFG.k_m))
    eta = np.zeros(2)
    c = port.command(np.array([5.0, 3.0]), eta, np.zeros(2), np.zeros(2), 1.0, 1.2, 0.01)
    assert np.allclose(c, 0.0)  # nothing came in: the robot is not pushed
    c = port.command(np.array([5.0, 3.0]), eta, np.zeros(2), np.array([100.0, 100.0]), 1.01, 1.21, 0.01)
    assert np.allclose(c, [5.0, 3.0])  # plenty came in: the command passes
    paper = FollowerPort(scheme_class("paper")(CFG), np.asarray(CFG.k_m))
    c = paper.command(np.array([5.0, 3.0]), eta, np.zeros(2), np.zeros(2), 1.0, 1.2, 0.01)
    assert np.allclose(c, [5.0, 3.0])


def test_the_wave_ports_close_the_loop_on_a_steady_speed() -> None:
    from bipedtele.control.schemes.runtime import FollowerPort, LeaderPort

    k_m = np.asarray(CFG.k_m)
    lead = LeaderPort(scheme_class("wave")(CFG), k_m)
    foll = FollowerPort(scheme_class("wave")(CFG), k_m)
    r = np.array([4.0, -2.0])
    eta = r.copy()
    fb_wave, _ = foll.outgoing(eta)
    z = lead.felt_speed(r, np.zeros(2), np.zeros(2), np.asarray(fb_wave), np.zeros(2), 1.0, 1.1, 0.001)
    assert np.allclose(z, r)  # no force while the robot keeps up
    u, _ = lead.outgoing(r)
    c = foll.command(np.zeros(2), eta, np.asarray(u), np.zeros(2), 1.0, 1.1, 0.01)
    assert np.allclose(c, r)
