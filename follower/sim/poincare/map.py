"""The walker's Poincare map at one operating point: fixed point, Jacobian (26), contraction, radius."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from bipedtele.config.profile import ConfigError
from bipedtele.control.config import ControlConfig
from bipedtele.follower.sim.config import SimConfig
from bipedtele.follower.sim.poincare.newton import NewtonResult, solve_fixed_point
from bipedtele.follower.sim.poincare.servo import WalkerServo
from bipedtele.follower.sim.poincare.state import CM, MapSettings, check_alignment, perturbation_sizes

LOG = logging.getLogger(__name__)


@dataclass
class WalkerMapResult:
    """One operating point of the walker's map."""

    sigma_r: list[float]
    T: float
    eps: float
    rho_walker: float
    eigenvalues: list[complex]
    fixed_point_speed: float
    fixed_point_v_hip: float
    fixed_point_turn: float
    residual: float
    spread: float
    contraction: float
    transient: float
    fallen: bool
    evaluations: int
    sim_seconds: float
    forward_std: float = math.nan
    turn_std: float = math.nan
    limit_cycle: bool = False
    newton: dict[str, Any] | None = None


class WalkerMap:
    """The walker's Poincare map at one ``(sigma_r, T, eps)``.

    Parameters
    ----------
    s_r, T, eps
        Real damping ``[sigma, tau]``, walking cycle [s] and joint servo [s].
    control : ControlConfig, optional
        Servo gains (default: the paper's).
    sim : SimConfig, optional
        The simulated NAO (default ``[sim]`` values, no obstacles).
    settings : MapSettings, optional
    """

    def __init__(
        self,
        s_r: Any,
        T: float,
        eps: float,
        *,
        control: ControlConfig | None = None,
        sim: SimConfig | None = None,
        settings: MapSettings | None = None,
    ) -> None:
        self.settings = settings or MapSettings()
        self.sim = sim or SimConfig()
        check_alignment(T, self.settings.physics_hz(self.sim), self.settings.control_rate_hz)
        lo, hi = self.sim.cycle_min_s, self.sim.cycle_max_s
        if not lo - 1e-9 <= T <= hi + 1e-9:
            raise ConfigError(f"T = {T:g} s: allowed: the simulated NAO's cycle range [{lo:g}, {hi:g}] s")
        self.control = control or ControlConfig()
        self.robot = self.settings.build_robot(self.sim)
        self.robot.connect()
        st = self.settings
        self.servo = WalkerServo(
            self.robot, self.control, s_r, T, eps, [st.v_ref, st.turn_ref], 1.0 / st.control_rate_hz
        )
        self.evaluations = 0
        self.sim_seconds = 0.0
        self.transient = math.nan

    def close(self) -> None:
        """Disconnect the simulation."""
        self.robot.disconnect()

    def __enter__(self) -> WalkerMap:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def steady(self) -> np.ndarray:
        """Walk from standing for ``warmup_s``, then ``average_cycles`` more cycles.

        Returns the fixed-point estimate: the mean of the section states of those cycles
        (for a walker that settles, the fixed point itself; for one whose touchdown state
        keeps wandering, e.g. between contact modes of the landing foot, the centre of the
        wandering, whose size :attr:`spread` reports; :meth:`newton` refines it).

        Over those cycles the measured speeds of every control tick give
        :attr:`forward_std` [cm/s] and :attr:`turn_std` [deg/s], their standard deviations
        within the cycle; :attr:`limit_cycle` is set when either exceeds its reference
        (``v_ref``, ``turn_ref``): the walker then oscillates by more than it is asked to
        walk. The turn loop's limit cycle at high turn damping (the servo saturating at
        +-25 deg/s within every cycle) is periodic in ``T``, so the section alone sees a
        fixed point there; this marker is what tells it apart.
        """
        sv, st = self.servo, self.settings
        sv.tick()
        sv.run(st.warmup_s)
        sv.run_to_section(st.foot, st.lead_s)
        states = [sv.state()]
        path = 0.0
        turned = 0.0
        elapsed = 0.0
        sv.trace = []
        for _ in range(st.average_cycles):
            p0 = self.robot._base()
            n = sv.run_to_section(st.foot, st.lead_s)
            p1 = self.robot._base()
            heading = p0[2] + 0.5 * _wrap(p1[2] - p0[2])
            path += (p1[0] - p0[0]) * math.cos(heading) + (p1[1] - p0[1]) * math.sin(heading)
            turned += _wrap(p1[2] - p0[2])
            elapsed += n * sv.dt
            states.append(sv.state())
        self.sim_seconds += st.warmup_s + elapsed + sv.T
        speeds = np.array(sv.trace)
        sv.trace = None
        self.forward_std, self.turn_std = (float(v) for v in speeds.std(axis=0))
        self.limit_cycle = self.forward_std > st.v_ref or self.turn_std > st.turn_ref
        arr = np.array(states)
        x0 = arr.mean(axis=0)
        d = perturbation_sizes(st.delta_scale)
        self.spread = float(np.max(np.abs(arr - x0) / d))
        self.speed = CM * path / elapsed if elapsed > 0 else 0.0
        self.turn_rate = math.degrees(turned / elapsed) if elapsed > 0 else 0.0
        self._x0 = x0
        self._snap = sv.snapshot()
        return x0.copy()

    def apply(self, x: np.ndarray) -> np.ndarray:
        """``P(x)``: the saved section with state ``x``, run for one walking cycle."""
        sv = self.servo
        sv.restore(self._snap)
        sv.set_state(x)
        n = sv.run_to_section(self.settings.foot, self.settings.lead_s)
        self.evaluations += 1
        self.sim_seconds += n * sv.dt
        return sv.state()

    def jacobian(self, x0: np.ndarray, scale: float | None = None) -> tuple[np.ndarray, bool]:
        """Central differences (26) around ``x0``: ``2 n`` evaluations of :meth:`apply`.

        ``scale`` is the factor on :data:`DELTAS` (default ``settings.delta_scale``).
        Returns the Jacobian and whether the walker fell in any evaluation.
        """
        sv = self.servo
        d = perturbation_sizes(self.settings.delta_scale if scale is None else scale)
        jac = np.empty((d.size, d.size))
        fallen = False
        for i in range(d.size):
            e = np.zeros(d.size)
            e[i] = d[i]
            plus = self.apply(x0 + e)
            fallen |= sv.fallen
            minus = self.apply(x0 - e)
            fallen |= sv.fallen
            jac[:, i] = (plus - minus) / (2.0 * d[i])
        return jac, fallen

    def residual(self, x: np.ndarray) -> np.ndarray:
        """``(P(x) - x) / delta``: the fixed-point residual in perturbation sizes (one evaluation)."""
        return (self.apply(x) - x) / perturbation_sizes(self.settings.delta_scale)

    def newton(self, x0: np.ndarray, *, jac: np.ndarray | None = None) -> NewtonResult:
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
        return solve_fixed_point(self, x0, jac=jac)

    def contraction(
        self, x0: np.ndarray, *, directions: int = 2, cycles: int = 20, size: float = 30.0, seed: int = 0
    ) -> float:
        """Measured contraction per cycle of a perturbation, without linearisation.

        From ``x0`` and from ``x0 + size * delta * v`` (``v`` a random unit direction in
        perturbation-size units) the walker runs ``cycles`` cycles; the distance between the
        two at the section, in perturbation-size units, shrinks (or grows) by a factor per
        cycle of ``(d_m / d_0)^(1/m)``. Returns the largest over ``directions``. For a
        smooth map this tends to the spectral radius; for the walker, whose contacts make
        the map non-smooth at the scale of the perturbations of (26), it is the check of
        what the Jacobian's radius claims.

        The horizon must outlast the transient: a perturbation of 30 sizes can first grow
        (up to 17 times in the first 3-4 cycles at the default operating point, when it
        switches the landing foot's contact and kicks the turn servo) and only then decay
        at 0.6-0.8 per cycle; over 10 cycles the estimate then reads about 1, over 20 it
        reads the decay (docs/method.md). The largest ``d_m / d_0`` over the horizon and the
        directions is kept in :attr:`transient`.
        """
        sv = self.servo
        d = perturbation_sizes(self.settings.delta_scale)
        rng = np.random.default_rng(seed)

        def run(x: np.ndarray) -> np.ndarray:
            sv.restore(self._snap)
            sv.set_state(x)
            out = []
            for _ in range(cycles):
                sv.run_to_section(self.settings.foot, self.settings.lead_s)
                out.append(sv.state())
            self.sim_seconds += cycles * sv.T
            return np.array(out)

        nominal = run(x0)
        worst = 0.0
        self.transient = 0.0
        for _ in range(directions):
            v = rng.standard_normal(d.size)
            v *= size / np.sqrt(np.mean(v * v))
            pert = run(x0 + v * d)
            dist = np.sqrt(np.mean(((pert - nominal) / d) ** 2, axis=1))
            worst = max(worst, float(dist[-1] / size) ** (1.0 / cycles))
            self.transient = max(self.transient, float(np.max(dist)) / size)
        return worst

    def analyse(self) -> WalkerMapResult:
        """Compute the fixed point, the Jacobian (26) by central differences and its spectral radius."""
        x0 = self.steady()
        sv = self.servo
        d = perturbation_sizes(self.settings.delta_scale)
        residual = float(np.max(np.abs(self.apply(x0) - x0) / d))
        jac, fallen = self.jacobian(x0)
        eig = np.linalg.eigvals(jac)
        contraction = self.contraction(x0) if self.settings.contraction else math.nan
        newton = None
        if self.settings.newton_iterations > 0:
            newton = self.newton(x0, jac=jac).as_dict()
            LOG.info(
                "newton: residual %.3g -> %.3g (max, perturbation sizes); radius at the fixed point %s",
                newton["residual_max"][0],
                newton["residual_max"][-1],
                newton["rho_by_scale"],
            )
        return WalkerMapResult(
            sigma_r=sv.s_r.tolist(),
            T=sv.T,
            eps=sv.eps,
            rho_walker=float(np.max(np.abs(eig))),
            eigenvalues=sorted(eig.tolist(), key=lambda z: -abs(z)),
            fixed_point_speed=float(self.speed),
            fixed_point_v_hip=float(x0[35]),
            fixed_point_turn=float(self.turn_rate),
            residual=residual,
            spread=self.spread,
            contraction=contraction,
            transient=self.transient,
            fallen=bool(fallen),
            evaluations=self.evaluations,
            sim_seconds=self.sim_seconds,
            forward_std=self.forward_std,
            turn_std=self.turn_std,
            limit_cycle=self.limit_cycle,
            newton=newton,
        )


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def walker_rho(s_r: Any, T: float, eps: float, **kw: Any) -> WalkerMapResult:
    """Build a :class:`WalkerMap`, analyse it, close it."""
    with WalkerMap(s_r, T, eps, **kw) as m:
        return m.analyse()
