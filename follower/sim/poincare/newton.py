"""The Newton solve of ``P(x) = x`` on the walker's map, and its result."""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from bipedtele.follower.sim.poincare.map import WalkerMap
from bipedtele.follower.sim.poincare.state import perturbation_sizes

LOG = logging.getLogger(__name__)


@dataclass
class NewtonResult:
    """A Newton solve of ``P(x) = x`` (:meth:`WalkerMap.newton`).

    Attributes
    ----------
    x : numpy.ndarray
        The last iterate (state units, :func:`state_names`).
    residual_max, residual_rms : list of float
        ``|P(x) - x|`` in perturbation sizes, largest and RMS over the state, at the
        start and after every accepted step.
    steps : list of float
        Largest component of every accepted step [perturbation sizes].
    damping : list of float
        The step factor accepted at every iteration (1, 1/2, ... 1/16).
    rho_by_scale : dict
        Radius of (26) at ``x`` per factor on :data:`DELTAS` (keys ``"0.3"``, ``"1"``, ...).
    fallen : bool
        The walker fell in some evaluation.
    """

    x: np.ndarray
    residual_max: list[float]
    residual_rms: list[float]
    steps: list[float]
    rho_by_scale: dict[str, float]
    fallen: bool
    damping: list[float] = dataclasses.field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready fields (without ``x``)."""
        return {
            "residual_max": self.residual_max,
            "residual_rms": self.residual_rms,
            "steps": self.steps,
            "damping": self.damping,
            "rho_by_scale": self.rho_by_scale,
            "fallen": self.fallen,
        }


def _rms(v: np.ndarray) -> float:
    return float(np.sqrt(np.mean(v * v)))


def solve_fixed_point(m: WalkerMap, x0: np.ndarray, *, jac: np.ndarray | None = None) -> NewtonResult:
    """Solve ``P(x) = x`` by damped Newton steps from ``x0``.

    In perturbation-size units ``y = x / delta`` the step solves ``(J_y - I) s = -r``
    (least squares, so a direction the map leaves alone costs nothing), ``J_y`` the
    central-difference Jacobian (26) at the current point. A step is capped at
    ``newton_max_step`` sizes per value, then halved up to 4 times until the RMS
    residual falls; with no fall the solve stops. At most ``newton_iterations``
    Jacobians (``jac``, the Jacobian at ``x0`` if already computed, counts as the
    first). At the last point the radius of (26) is measured for every factor of
    ``newton_scales``.
    """
    st = m.settings
    d = perturbation_sizes(st.delta_scale)
    x = np.asarray(x0, dtype=float).copy()
    r = m.residual(x)
    res_max, res_rms, steps, damping = [float(np.max(np.abs(r)))], [_rms(r)], [], []
    fallen = m.servo.fallen
    for k in range(st.newton_iterations):
        if k > 0 or jac is None:
            jac, f = m.jacobian(x)
            fallen |= f
        jy = jac * d[None, :] / d[:, None]
        step = np.linalg.lstsq(jy - np.eye(d.size), -r, rcond=1e-6)[0]
        big = float(np.max(np.abs(step)))
        if big > st.newton_max_step:
            step *= st.newton_max_step / big
        alpha = 1.0
        for _ in range(5):
            trial = x + alpha * step * d
            r_new = m.residual(trial)
            fallen |= m.servo.fallen
            if _rms(r_new) < res_rms[-1]:
                break
            alpha *= 0.5
        else:
            LOG.info("newton: no step lowers the residual after %d iterations", k)
            break
        x, r = trial, r_new
        res_max.append(float(np.max(np.abs(r))))
        res_rms.append(_rms(r))
        steps.append(alpha * float(np.max(np.abs(step))))
        damping.append(alpha)
        LOG.info("newton %d: step %.2f sizes, residual rms %.3g max %.3g", k + 1, steps[-1], res_rms[-1], res_max[-1])
    rho: dict[str, float] = {}
    for sc in st.newton_scales:
        jk, f = m.jacobian(x, sc)
        fallen |= f
        rho[f"{sc:g}"] = float(np.max(np.abs(np.linalg.eigvals(jk))))
    return NewtonResult(x, res_max, res_rms, steps, rho, bool(fallen), damping)
