"""The cascade calibration V.1-V.3 (Sec. 3.6) as one object.

* **V.1 (offline)**: the reference model ``D``, the gains ``k_s``, ``k_m``, ``k_g``, the
  observer ``beta_r`` and ``beta_e`` come from the ``[control]`` section; the paper's
  values are the defaults (``D = diag(4.5, 1)``, ``k_s = I``, ``beta_r = 0.5 I``,
  ``eps = 0.5``, ``v_ref = 5 cm/s``, ``turn_ref = 4 deg/s``, ``dq = 1``, ``dqdot = 0.375``,
  ``dp = 0.7``). :meth:`Calibration.offline_report` evaluates Definitions 1-3 for them.
* **V.2 (online)**: :meth:`Calibration.damping` - ``alpha_m`` and ``sigma_e`` from the
  delay estimates by (40) (:func:`~bipedtele.control.damping.schedule_damping`).
* **V.3 (online)**: :meth:`Calibration.choose` - V.2 then ``(sigma_r, T, eps)`` by (30)
  (:class:`~bipedtele.control.online.OnlineChooser`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from bipedtele.control.config import ControlConfig
from bipedtele.control.damping import Damping, schedule_damping
from bipedtele.control.hybrid import T_min, beta_e_def3, s_r_min
from bipedtele.control.online import Choice, OnlineChooser

__all__ = ["Calibration", "Setpoint"]


@dataclass(frozen=True, eq=False)  # array fields: compare fields explicitly
class Setpoint:
    """Everything the two sides need for the current delays.

    Attributes
    ----------
    h1, h2 : float
        Delay estimates used [s].
    damping : Damping
        V.2 result (``alpha_m`` for the leader, ``s_e`` for the equivalent follower).
    choice : Choice
        V.3 result (``s_r``, ``T``, ``eps`` for the real follower).
    """

    h1: float
    h2: float
    damping: Damping
    choice: Choice


@dataclass
class Calibration:
    """Cascade calibration with a prebuilt online table.

    Parameters
    ----------
    cfg : ControlConfig
        The ``[control]`` section (V.1 values).
    """

    cfg: ControlConfig
    chooser: OnlineChooser = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.chooser = OnlineChooser(self.cfg)

    @classmethod
    def from_config(cls, cfg: ControlConfig | None = None) -> Calibration:
        """Build from a ``[control]`` section (default: the paper's values)."""
        return cls(cfg if cfg is not None else ControlConfig())

    def damping(self, h1: float, h2: float) -> Damping:
        """V.2: ``alpha_m`` [N s/m] and ``sigma_e`` from delays ``h1``, ``h2`` [s]."""
        return schedule_damping(h1, h2, self.cfg)

    def choose(self, h1: float, h2: float) -> Setpoint:
        """V.2 then V.3 for delays ``h1``, ``h2`` [s] (cheap: < 1 ms)."""
        d = self.damping(h1, h2)
        return Setpoint(h1=float(h1), h2=float(h2), damping=d, choice=self.chooser.choose(d.s_e))

    def offline_report(self, dt: float = 0.01, level: float = 0.9) -> dict[str, Any]:
        """V.1 figures: Definitions 1-3 at the configured values.

        ``level`` is the per-cycle contraction used for Definitions 1-2 (with ``level = 1``
        they are vacuous for the linear reduced model; docs/method.md); Definition 3 uses
        the forward-Euler discretisation at ``dt`` [s] (vacuous under exact ZOH).
        """
        t_min = T_min(self.cfg, level=level)
        return {
            "T_min_s": t_min,
            "s_r_min": None if t_min is None else s_r_min(self.cfg, t_min, level=level),
            "beta_e_def3_euler_s": beta_e_def3(self.cfg, dt),
            "beta_e_def3_zoh_s": beta_e_def3(self.cfg, dt, method="zoh"),
            "level": level,
            "dt_s": dt,
        }
