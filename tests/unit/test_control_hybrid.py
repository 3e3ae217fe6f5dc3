"""Reduced hybrid follower (20)-(23), Poincare map and Jacobian (24)-(26), Definitions 1-3."""

from __future__ import annotations

import numpy as np
import pytest
from bipedtele.control.config import ControlConfig
from bipedtele.control.hybrid import (
    T_min,
    analytic_jacobian,
    beta_e_def3,
    fixed_point,
    jacobian_central,
    poincare_map,
    rho_hybrid,
    rho_hybrid_grid,
)

pytestmark = pytest.mark.compute  # CPU-bound and deterministic: run beside the other unit tests (scripts/test.sh)

CFG = ControlConfig()


@pytest.mark.parametrize(
    ("s_r", "T", "eps", "dp"),
    [([2.0, 3.0], 1.2, 0.5, 0.7), ([0.0, 10.0], 0.5, 0.05, 0.25), ([10.0, 0.0], 5.0, 1.0, 0.5)],
)
def test_central_difference_jacobian_equals_analytic(s_r: list[float], T: float, eps: float, dp: float) -> None:
    jc = jacobian_central(s_r, T, eps, dp, CFG)  # numerical integration, paper's dq/dqdot
    ja = analytic_jacobian(s_r, T, eps, dp, CFG)
    np.testing.assert_allclose(jc, ja, atol=1e-6)
    assert rho_hybrid(s_r, T, eps, dp, CFG) == pytest.approx(np.abs(np.linalg.eigvals(ja)).max(), rel=1e-9)


def test_fixed_point_is_a_fixed_point_and_reset_scales_hip_speed() -> None:
    s_r, T, eps, dp = [1.0, 1.0], 1.0, 0.5, 0.7
    e = fixed_point(s_r, T, eps, dp, CFG)
    np.testing.assert_allclose(poincare_map(e, s_r, T, eps, dp, CFG), e, atol=1e-8)
    # zero error just before impact: the hip speed v_ref becomes dp v_ref, error (1-dp) v_ref
    after = poincare_map(np.zeros(16), s_r, 1e-9, eps, dp, CFG)
    assert after[0] == pytest.approx((1 - dp) * CFG.v_ref)


def test_rho_grid_matches_scalar_and_decreases_with_T() -> None:
    s = np.linspace(0, 10, 6)[:, None]
    t = np.linspace(0.5, 5, 10)[None, :]
    grid = rho_hybrid_grid(s, t, CFG.eps, CFG.dp, CFG)
    assert grid[2, 3] == pytest.approx(rho_hybrid([s[2, 0]] * 2, t[0, 3], CFG.eps, CFG.dp, CFG))
    assert np.all(np.diff(grid, axis=1) < 0)
    assert np.all((grid > 0) & (grid < 1))


def test_definitions() -> None:
    # rho < 1 for every T > 0 in the linear model: Definition 1 with level 1 is the lower bound
    assert T_min(CFG) == pytest.approx(1e-3)
    t9 = T_min(CFG, level=0.9)
    assert t9 is not None
    assert rho_hybrid([CFG.s_e_min] * 2, t9, CFG.eps_range[0], CFG.dp, CFG) == pytest.approx(0.9, abs=1e-9)
    b = beta_e_def3(CFG, 0.01)
    assert b is not None and 0 < b < 0.1
    assert beta_e_def3(CFG, 0.01, method="zoh") == pytest.approx(1e-4)


@pytest.mark.parametrize(("sigma", "T", "dp"), [(2.0, 1.3, 0.7), (0.0, 0.5, 0.25), (8.0, 4.0, 0.9)])
def test_orbit_speed_deficit_equals_the_simulated_orbit(sigma: float, T: float, dp: float) -> None:
    from bipedtele.control.hybrid import orbit_speed_deficit
    from bipedtele.control.linalg import mat2, zoh2

    D, k, b, r, dt = 4.5, 1.0, 0.5, 5.0, 1e-3
    a = mat2(-k / D - sigma / (D * b), sigma / (D * b), 1 / b, -1 / b)
    phi, gam = zoh2(a, np.array([[k / D], [0.0]]), dt)
    x = np.zeros(2)
    n = round(T / dt)
    for _ in range(300):  # walk until the orbit is periodic, then average one cycle
        speeds = []
        for _ in range(n):
            speeds.append(x[0])
            x = phi @ x + gam[:, 0] * r
        x[0] *= dp
    assert orbit_speed_deficit(sigma, T, D, k, b, dp) == pytest.approx(1 - np.mean(speeds) / r, abs=2e-3)
    # no reset, no deficit; the deficit grows as the cycle shortens
    assert orbit_speed_deficit(sigma, T, D, k, b, 1.0) == pytest.approx(0.0, abs=1e-12)
    assert orbit_speed_deficit(sigma, T / 2, D, k, b, dp) > orbit_speed_deficit(sigma, T, D, k, b, dp)
