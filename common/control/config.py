"""The ``[control]`` section: the paper's cascade-calibration parameters (Sec. 3.6, V.1-V.3).

Units: the forward channel is in cm/s, the turn channel in deg/s (the paper's units);
two-element lists are ``[forward, turn]``. Defaults are the paper's values where it gives
them (Sec. 3.2.2, eq. 27) and documented choices elsewhere (docs/method.md).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal

from bipedtele.config.fields import param
from bipedtele.control.schemenames import scheme_names

__all__ = ["ControlConfig"]


def _pair(default: tuple[float, float], **kw: Any) -> Any:
    return param(default_factory=lambda: list(default), **kw)


@dataclass(frozen=True)
class ControlConfig:
    """Controller parameters for both sides.

    Attributes are ``[forward, turn]`` pairs unless noted.
    """

    D: list[float] = _pair((4.5, 1.0), lo=0.0, lo_open=True, doc="reference model mass M and inertia I (eq. 20, 22)")
    k_s: list[float] = _pair((1.0, 1.0), lo=0.0, lo_open=True, doc="follower proportional gains k_v, k_delta")
    k_m: list[float] = _pair(
        (0.4, 0.4), lo=0.0, lo_open=True, unit="N per (cm/s) | N per (deg/s)", doc="leader gain (eq. 31)"
    )
    k_g: list[float] = _pair(
        (160.0, 200.0),
        lo=0.0,
        lo_open=True,
        unit="(cm/s)/m | (deg/s)/m",
        doc="handle position -> forward/turn speed (eq. 7, 11)",
    )
    beta_r: list[float] = _pair((0.5, 0.5), lo=0.0, lo_open=True, unit="s", doc="observer time constant (eq. 12)")
    beta_e: list[float] = _pair(
        (0.5, 0.5), lo=0.0, lo_open=True, unit="s", doc="equivalent follower filter time constant (eq. 29)"
    )
    k_z: list[float] = _pair((1.0, 0.0), lo=0.0, doc="impedance on the fictitious force f_v (eq. 20, 22)")
    eps: float = param(0.5, lo=0.0, lo_open=True, unit="s", doc="nominal joint-servo gain (eq. 21)")
    dp: float = param(0.7, lo=0.0, hi=1.0, lo_open=True, doc="reset-map hip-speed factor at impact")
    dp_turn: float = param(
        1.0,
        lo=0.0,
        hi=1.0,
        lo_open=True,
        doc="reset-map turn-speed factor at impact (1 = the impact leaves the turn speed alone)",
    )
    dq: float = param(1.0, lo=0.0, lo_open=True, doc="Poincare Jacobian perturbation of positions (eq. 26)")
    dqdot: float = param(0.375, lo=0.0, lo_open=True, doc="Poincare Jacobian perturbation of velocities (eq. 26)")
    v_ref: float = param(5.0, lo=0.0, unit="cm/s", doc="calibration forward speed")
    turn_ref: float = param(4.0, lo=0.0, unit="deg/s", doc="calibration turn speed")
    margin: float = param(0.2, lo=0.0, hi=10.0, doc="relative margin on the conditions (40)")
    alpha_m_min: float = param(
        0.05, lo=0.0, lo_open=True, unit="N s/m", doc="lower bound of alpha_m (leader damping, per channel)"
    )
    s_e_min: float = param(0.05, lo=0.0, lo_open=True, unit="same as D", doc="lower bound of sigma_e (sigma_e_min > 0)")
    s_r_range: list[float] = _pair((0.0, 10.0), lo=0.0, hi=100.0, doc="bounds of the real damping sigma_r")
    T_range: list[float] = _pair((0.5, 5.0), lo=0.05, hi=20.0, unit="s", doc="bounds of the walking cycle time")
    eps_range: list[float] = _pair((0.05, 1.0), lo=0.001, hi=10.0, unit="s", doc="bounds of eps")
    k_sigma: float = param(1.0, lo=0.0, doc="weight of |sigma_r - sigma_e| in (30)")
    k_wt: float = param(1.0, lo=0.0, unit="1/s", doc="weight of T in (30)")
    k_eps: float = param(1.0, lo=0.0, unit="1/s", doc="weight of eps in (30)")
    tolerance: float = param(0.01, lo=0.0, lo_open=True, hi=1.0, doc="tolerance of the equality constraint in (30)")
    equivalent_period: Literal["cycle", "fixed"] = param(
        "cycle",
        doc="period over which (29) is discretised in (30): the candidate walking cycle T, or equivalent_period_s",
    )
    equivalent_period_s: float = param(
        0.01,
        lo=0.001,
        hi=20.0,
        unit="s",
        doc="the fixed period of (29) in (30) when equivalent_period = 'fixed' (0.01 s: the follower's control period)",
    )
    hybrid_model: Literal["paper", "speed-loop", "walker"] = param(
        "paper",
        doc="model on the hybrid side of the online choice (30): the reduced model with the paper's dp and k_v; "
        "with calibrated_dp and calibrated_k_v (bipedtele calibrate: the follower's own speed loop); or the "
        "tabulated Poincare map of the simulated walker (docs/walker_map.md)",
    )
    calibrated_dp: float = param(
        1.0,
        lo=0.0,
        hi=1.0,
        lo_open=True,
        doc="reset factor identified on the simulated walker (bipedtele calibrate, default [sim]; the torso keeps 1.051 of its speed across a touchdown: "
        "the impact costs no speed, the reset (22) gets 1; docs/method.md)",
    )
    calibrated_k_v: float = param(
        1.205,
        lo=0.0,
        lo_open=True,
        doc="forward gain k_v identified on the simulated walker (bipedtele calibrate, default [sim]; docs/method.md)",
    )

    scheme: str = param(
        "paper",
        doc="bilateral control scheme, a registered name (docs/schemes.md; bipedtele compare runs them all)",
    )
    wave_window_s: float = param(
        0.5,
        lo=0.01,
        hi=10.0,
        unit="s",
        doc="window over which every runner (the real loops, the comparison, the studies) measures the "
        "received-wave gain sqrt(1 - dh/dt) (docs/schemes.md)",
    )
    worst_delays_s: list[float] = _pair(
        (0.7, 0.7),
        lo=0.0,
        hi=60.0,
        unit="s",
        doc="largest forward and backward delays the link may have [h1, h2]: what pd-worst-case sizes its damping for",
    )

    def __post_init__(self) -> None:
        if self.scheme not in scheme_names():
            raise ValueError(f"scheme = {self.scheme!r}: allowed: {', '.join(scheme_names())}")
        for name in (
            "D",
            "k_s",
            "k_m",
            "k_g",
            "beta_r",
            "beta_e",
            "k_z",
            "s_r_range",
            "T_range",
            "eps_range",
            "worst_delays_s",
        ):
            value = getattr(self, name)
            if len(value) != 2:
                raise ValueError(f"{name} = {value!r}: allowed: a list of exactly 2 numbers")
        for name in ("s_r_range", "T_range", "eps_range"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"{name} = {[lo, hi]!r}: allowed: [low, high] with low < high")

    def hybrid(self) -> ControlConfig:
        """Return the parameters of the reduced model (20)-(23) that the online choice (30) uses.

        ``hybrid_model = "paper"``: this config. ``"speed-loop"``: ``dp`` and the forward
        gain ``k_s[0]`` replaced by ``calibrated_dp`` and ``calibrated_k_v`` (the
        equivalent follower (29) and the servo keep ``k_s``). ``"walker"``: this config
        (the online choice uses the walker table, not the reduced model; code that still
        evaluates the reduced model gets the paper's values).
        """
        if self.hybrid_model in ("paper", "walker"):
            return self
        return replace(self, dp=self.calibrated_dp, k_s=[self.calibrated_k_v, self.k_s[1]], hybrid_model="paper")
