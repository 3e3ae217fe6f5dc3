"""Leader law (31), damping scheduler (40), observer (12), equivalent follower (29)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import schedule_damping
from bipedtele.control.equivalent import (
    EquivalentFollower,
    equivalent_matrices,
    equivalent_spectral_radius,
)
from bipedtele.control.leader_law import leader_force
from bipedtele.control.observer import Observer

CFG = ControlConfig()


def test_leader_force_is_eq31() -> None:
    f = leader_force(
        [0.01, -0.02], [0.1, 0.0], [1.0, 2.0], k_m=[0.4, 0.5], k_g=[160, 200], alpha_m=[3.0, 4.0], g_m=[0.2, 0.0]
    )
    expected = np.array([-0.4 * (1.6 - 1.0) + 0.2 - 0.3, -0.5 * (-4.0 - 2.0)])
    np.testing.assert_allclose(f, expected, rtol=1e-12)


def test_damping_zero_delay_gives_lower_bounds() -> None:
    d = schedule_damping(0.0, 0.0, CFG)
    np.testing.assert_allclose(d.alpha_m, CFG.alpha_m_min)
    np.testing.assert_allclose(d.s_e, CFG.s_e_min)
    assert np.all(d.lambda_m > 0) and np.all(d.lambda_se > 0)


def test_damping_exactly_at_the_boundary_with_zero_margin() -> None:
    cfg = ControlConfig(margin=0.0)
    h1, h2 = 0.3, 0.2
    d = schedule_damping(h1, h2, cfg)
    k_pos = np.array(cfg.k_m) * np.array(cfg.k_g)
    np.testing.assert_allclose(d.alpha_m, k_pos * (h1 + h2 / 4))
    np.testing.assert_allclose(d.lambda_m, 0.0, atol=1e-12)
    # sigma_e: choose D so that the bound sigma_e = k_s (h1/4 + h2) - D is exactly s_e_min
    foll = h1 / 4 + h2
    cfg2 = ControlConfig(margin=0.0, D=[foll - 0.05, foll - 0.05], s_e_min=0.05)
    d2 = schedule_damping(h1, h2, cfg2)
    np.testing.assert_allclose(d2.s_e, 0.05)
    np.testing.assert_allclose(d2.lambda_se, 0.0, atol=1e-12)
    # just past it, the bound becomes active and the slack stays 0
    d3 = schedule_damping(h1, h2 + 0.01, cfg2)
    assert np.all(d3.s_e > 0.05)
    np.testing.assert_allclose(d3.lambda_se, 0.0, atol=1e-12)


def test_damping_margin_makes_conditions_strict_and_huge_delay_is_finite() -> None:
    for h1, h2 in ((0.25, 0.12), (1000.0, 2000.0)):
        d = schedule_damping(h1, h2, CFG)
        assert np.all(np.isfinite(d.alpha_m)) and np.all(np.isfinite(d.s_e))
        np.testing.assert_allclose(d.lambda_m, CFG.margin * (h1 + h2 / 4), rtol=1e-9)
        assert np.all(d.lambda_se > 0)
    big = schedule_damping(1000.0, 2000.0, CFG)
    np.testing.assert_allclose(big.lambda_se, CFG.margin * (1000.0 / 4 + 2000.0), rtol=1e-9)
    # smallest: lowering alpha_m or sigma_e by 1 % breaks the margin
    k_pos = np.array(CFG.k_m) * np.array(CFG.k_g)
    assert np.all(0.99 * big.alpha_m / k_pos - 1000.0 - 500.0 < CFG.margin * 1500.0)


def test_observer_converges_exactly() -> None:
    obs = Observer([0.5, 0.25], dt=0.01)
    obs.reset([0.0, 10.0])
    for _ in range(100):  # 1 s
        z = obs.step([4.0, 0.0])
    np.testing.assert_allclose(z, [4.0 * (1 - math.exp(-2.0)), 10.0 * math.exp(-4.0)], rtol=1e-12)
    for _ in range(2000):
        z = obs.step([4.0, 0.0])
    np.testing.assert_allclose(z, [4.0, 0.0], atol=1e-9)


def test_equivalent_follower_step_is_continuous_and_converges() -> None:
    f = EquivalentFollower.from_config(CFG, dt=0.01)
    f.reset(0.0)
    out = np.array([f.step([5.0, 4.0], [CFG.s_e_min] * 2) for _ in range(6000)])
    jumps = np.abs(np.diff(np.vstack([[0.0, 0.0], out]), axis=0)).max(axis=0)
    assert np.all(jumps < 0.05)  # a 5 cm/s step input moves z_e by < 1 % per 10 ms
    np.testing.assert_allclose(out[-1], [5.0, 4.0], rtol=1e-3)


def test_equivalent_zoh_is_exact_at_any_period() -> None:
    fine = EquivalentFollower.from_config(CFG, dt=0.001)
    coarse = EquivalentFollower.from_config(CFG, dt=0.25)
    for _ in range(2000):
        zf = fine.step([3.0, -2.0], [1.0, 0.3])
    for _ in range(8):
        zc = coarse.step([3.0, -2.0], [1.0, 0.3])
    np.testing.assert_allclose(zf, zc, rtol=1e-9)
    np.testing.assert_allclose(fine.state, coarse.state, rtol=1e-9)


def test_equivalent_spectral_radius_matches_eigenvalues() -> None:
    from scipy.linalg import expm

    for s_e in ([0.05, 0.05], [2.0, 0.4], [9.0, 9.0]):
        a, _ = equivalent_matrices(s_e, CFG.D, CFG.k_s, CFG.beta_e)
        rad = max(np.abs(np.linalg.eigvals(expm(a[c] * 0.7))).max() for c in range(2))
        assert equivalent_spectral_radius(s_e, CFG, 0.7) == pytest.approx(rad, rel=1e-10)
