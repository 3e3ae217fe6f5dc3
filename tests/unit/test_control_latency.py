"""The reduced turn loop closed through the gait's latency (bipedtele.control.latency)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.hybrid import rho_speed_block, speed_block_matrix
from bipedtele.control.latency import (
    delay_onset,
    delay_radius,
    latched_onset,
    latched_radius,
    latched_step_map,
    latched_step_map_discrete,
    turn_block,
)
from scipy.optimize import brentq

pytestmark = [pytest.mark.timeout(60)]

CFG = ControlConfig()
I_, K, BETA = CFG.D[1], CFG.k_s[1], CFG.beta_r[1]


@pytest.mark.parametrize("tau", [0.0, 0.7, 2.5, 8.0])
def test_no_latency_is_the_reduced_turn_block(tau: float) -> None:
    """With ``v = eta`` the "paper" form has the spectrum of (22)-(23); the radius per cycle is the hybrid one."""
    a, b = turn_block(tau, CFG, "paper")
    closed = a + np.outer(b, [1.0, 0.0])
    ref = np.asarray(speed_block_matrix(tau, I_, K, BETA))
    assert np.allclose(np.sort_complex(np.linalg.eigvals(closed)), np.sort_complex(np.linalg.eigvals(ref)))
    for T in (0.8, 1.2):
        want = float(rho_speed_block(tau, T, I_, K, BETA, 1.0))
        assert delay_radius(tau, T, 0.0, CFG) == pytest.approx(want, rel=1e-10)


def test_no_delay_no_onset() -> None:
    """Without latency the turn loop is stable at every tau (what the reduced model says)."""
    assert delay_onset(0.0, CFG) == (math.inf, pytest.approx(math.nan, nan_ok=True))


def test_delay_margin_of_a_first_order_lag() -> None:
    """k = 0: the loop is ``(tau/I) e^{-sL} / (beta s + 1)``, marginal at ``w L + atan(beta w) = pi``."""
    cfg = ControlConfig(k_s=[1.0, 1e-12])
    L = 0.4
    w = brentq(lambda x: x * L + math.atan(BETA * x) - math.pi, 1e-3, 100.0)
    tau_hand = I_ * math.sqrt(1.0 + (BETA * w) ** 2)
    tau, w_got = delay_onset(L, cfg, "paper")
    assert tau == pytest.approx(tau_hand, rel=1e-6)
    assert w_got == pytest.approx(w, rel=1e-6)


@pytest.mark.parametrize("form", ["paper", "servo"])
def test_delay_radius_crosses_one_at_the_onset(form: str) -> None:
    """The state-augmented map (fine dt) agrees with the closed-form onset."""
    L, T = 0.4, 0.8
    tau, _ = delay_onset(L, CFG, form)  # type: ignore[arg-type]
    assert delay_radius(0.97 * tau, T, L, CFG, form, dt=0.002) < 1.0  # type: ignore[arg-type]
    assert delay_radius(1.03 * tau, T, L, CFG, form, dt=0.002) > 1.0  # type: ignore[arg-type]


def test_issue_check_reproduced() -> None:
    """The issue's check: a half-cycle delay with the servo's form, 2.56 (T = 0.8 s) and 1.90 (1.2 s)."""
    assert delay_onset(0.4, CFG, "servo")[0] == pytest.approx(2.56, abs=0.01)
    assert delay_onset(0.6, CFG, "servo")[0] == pytest.approx(1.90, abs=0.015)


@pytest.mark.parametrize("T", [0.8, 1.0, 1.2])
def test_latched_flip_by_hand(T: float) -> None:
    """k = 0, "paper" form: eigenvalues 1 and ``a - (tau/I)(1 - a)``: the flip at ``I coth(h / (2 beta))``."""
    cfg = ControlConfig(k_s=[1.0, 1e-12])
    h = T / 2.0
    tau, lam = latched_onset(T, cfg, "paper")
    assert tau == pytest.approx(I_ / math.tanh(h / (2.0 * BETA)), rel=1e-6)
    assert lam.real == pytest.approx(-1.0, abs=1e-6)
    a = math.exp(-h / BETA)
    eig = np.sort(np.linalg.eigvals(latched_step_map(1.3, h, cfg, "paper")).real)
    assert eig == pytest.approx(np.sort([1.0, a - 1.3 / I_ * (1.0 - a)]), abs=1e-9)


@pytest.mark.parametrize("tau", [0.5, 2.0])
def test_latched_tends_to_no_latency(tau: float) -> None:
    """Latching every h -> 0 tends to the continuous loop (22)-(23)."""
    T, n = 1.0, 4000
    m = np.linalg.matrix_power(latched_step_map(tau, T / n, CFG, "paper"), n)
    want = float(rho_speed_block(tau, T, I_, K, BETA, 1.0))
    assert float(np.max(np.abs(np.linalg.eigvals(m)))) == pytest.approx(want, abs=2e-3)


@pytest.mark.parametrize("form", ["paper", "servo"])
def test_discrete_servo_tends_to_continuous(form: str) -> None:
    """The 50 Hz servo's step map tends to the continuous one as dt -> 0."""
    T = 0.8
    for tau in (1.0, 2.4):
        cont = latched_radius(tau, T, CFG, form)  # type: ignore[arg-type]
        fine = latched_radius(tau, T, CFG, form, dt=0.0005)  # type: ignore[arg-type]
        assert fine == pytest.approx(cont, abs=2e-3)
    assert latched_onset(T, CFG, form, dt=0.0005)[0] == pytest.approx(latched_onset(T, CFG, form)[0], abs=5e-3)  # type: ignore[arg-type]


def test_discrete_map_rejects_misaligned_step() -> None:
    with pytest.raises(ValueError, match="multiple of dt"):
        latched_step_map_discrete(1.0, 0.41, CFG, "servo", 0.02)


def test_latched_onset_falls_with_the_cycle() -> None:
    """A longer step (larger T) is a longer hold: the flip comes at a lower turn damping."""
    taus = [latched_onset(T, CFG, "servo", dt=0.02)[0] for T in (0.8, 1.0, 1.2)]
    assert taus[0] > taus[1] > taus[2] > 0
