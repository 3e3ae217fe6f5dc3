"""The factorial grid of schemes: damping x what is fed back x passivity controller.

A named scheme bundles three choices; the comparison separates them (docs/schemes.md, "The
factorial design"). Each cell of the grid is a class composed of the existing pieces:

* **damping** (:data:`DAMPINGS`): ``floor``, (40) at zero delay, its lower bounds
  (``alpha_m_min``, ``s_e_min``); ``ratio``, a fixed handle damping ratio
  :data:`FIXED_RATIO` for the comparison's handle mass :data:`HANDLE_MASS_KG`
  (:func:`ratio_damping`), ``sigma_e`` at its floor; ``scheduled``, (40) on the measured
  delays; ``worst``, (40) at the run's largest delays, held;
* **what is fed back** (:data:`FEEDBACKS`): ``ze``, the equivalent follower's ``z_e`` (29)
  (:class:`~bipedtele.control.schemes.paper.EquivalentSpeed`); ``speed``, the robot's
  measured speed (:class:`~bipedtele.control.schemes.pd.MeasuredSpeed`); ``wave``, wave
  variables with the time-varying-delay gain (:class:`~bipedtele.control.schemes.wave.Wave`);
* **passivity controller** (:data:`PASSIVITY`): ``off``, or ``on``, the observers and
  controllers at both ports (:class:`~bipedtele.control.schemes.passivity.Passivity`).

The six named schemes are cells of the grid (:data:`NAMED_CELLS`): ``paper`` is
``scheduled/ze``, ``paper-constant`` ``floor/ze``, ``pd-measured`` ``scheduled/speed``,
``pd-worst-case`` ``worst/speed``, ``wave`` ``floor/wave``, ``tdpa`` ``floor/speed/pc``.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from bipedtele.control.reduced import StudyParams
from bipedtele.control.schemes.base import Scheme, held, scheduled, zero_delay
from bipedtele.control.schemes.paper import EquivalentSpeed
from bipedtele.control.schemes.passivity import Passivity
from bipedtele.control.schemes.pd import MeasuredSpeed
from bipedtele.control.schemes.wave import Wave

__all__ = [
    "DAMPINGS",
    "FEEDBACKS",
    "FIXED_RATIO",
    "HANDLE_MASS_KG",
    "NAMED_CELLS",
    "PASSIVITY",
    "Cell",
    "cell_name",
    "grid",
    "ratio_damping",
]

#: Damping ratio of the ``ratio`` damping (the handle as a mass-spring-damper).
FIXED_RATIO = 0.3
#: Handle mass the ``ratio`` damping is sized for [kg] (the comparison's simulated handle).
HANDLE_MASS_KG = StudyParams().leader_mass_kg


def ratio_damping(k_pos: np.ndarray | float, mass_kg: float = HANDLE_MASS_KG, ratio: float = FIXED_RATIO) -> np.ndarray:
    """Return the leader damping [N s/m] that gives the handle the damping ratio ``ratio``.

    Parameters
    ----------
    k_pos : array_like
        Handle position stiffness ``k_m k_g`` per channel [N/m].
    mass_kg : float
        Handle mass [kg].
    ratio : float
        Damping ratio (1: critical).
    """
    return np.asarray(ratio * 2.0 * np.sqrt(np.asarray(k_pos, dtype=float) * mass_kg), dtype=float)


class FloorDamping(Scheme):
    """(40) at zero delay, its lower bounds, held."""

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the lower bounds ``alpha_m_min``, ``s_e_min``."""
        return zero_delay(h1_s, self.cfg)


class RatioDamping(Scheme):
    """A fixed handle damping ratio :data:`FIXED_RATIO`, ``sigma_e`` at its floor."""

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``alpha_m`` of :func:`ratio_damping` (at least ``alpha_m_min``), ``s_e_min``."""
        alpha_0, s_e = zero_delay(h1_s, self.cfg)
        k_pos = np.asarray(self.cfg.k_m, dtype=float) * np.asarray(self.cfg.k_g, dtype=float)
        return np.maximum(alpha_0, ratio_damping(k_pos)[None, :]), s_e


class ScheduledDamping(Scheme):
    """(40) on the measured delays."""

    adapts = True

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at every delay estimate."""
        return scheduled(h1_s, h2_s, self.cfg)


class WorstDamping(Scheme):
    """(40) at the run's largest delays, held."""

    def damping(self, h1_s: np.ndarray, h2_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(40) at ``worst_delays_s``, held."""
        w1, w2 = self.worst_delays_s
        return held(w1, w2, self.cfg, int(np.asarray(h1_s).shape[0]))


#: Damping axis: level -> the class that holds that damping.
DAMPINGS: dict[str, type] = {  # abstract halves of a scheme: a type, not a type[Scheme]
    "floor": FloorDamping,
    "ratio": RatioDamping,
    "scheduled": ScheduledDamping,
    "worst": WorstDamping,
}
#: Feedback axis: level -> the coupling class (port laws).
FEEDBACKS: dict[str, type] = {"ze": EquivalentSpeed, "speed": MeasuredSpeed, "wave": Wave}
#: Passivity axis: level -> whether the passivity observers and controllers act.
PASSIVITY: dict[str, bool] = {"off": False, "on": True}

_DAMPING_TITLES = {
    "floor": "(40) at zero delay (floor)",
    "ratio": f"handle damping ratio {FIXED_RATIO:g}",
    "scheduled": "(40) on the measured delays",
    "worst": "(40) at the run's worst delays, held",
}
_FEEDBACK_TITLES = {"ze": "z_e fed back", "speed": "robot's speed fed back", "wave": "wave variables"}


class Cell(NamedTuple):
    """One cell's levels on the three axes."""

    damping: str
    feedback: str
    passivity: str


def cell_name(cell: Cell) -> str:
    """Return the cell's name: ``damping/feedback``, with ``/pc`` when the passivity controller acts."""
    return f"{cell.damping}/{cell.feedback}" + ("/pc" if PASSIVITY[cell.passivity] else "")


#: The named schemes as cells of the grid.
NAMED_CELLS: dict[str, Cell] = {
    "paper": Cell("scheduled", "ze", "off"),
    "paper-constant": Cell("floor", "ze", "off"),
    "pd-measured": Cell("scheduled", "speed", "off"),
    "pd-worst-case": Cell("worst", "speed", "off"),
    "wave": Cell("floor", "wave", "off"),
    "tdpa": Cell("floor", "speed", "on"),
}


def _compose(cell: Cell) -> type[Scheme]:
    """Return the class of one cell: the passivity mixin (if on), then the damping, then the coupling."""
    name = cell_name(cell)
    bases: tuple[type, ...] = (DAMPINGS[cell.damping], FEEDBACKS[cell.feedback])
    if PASSIVITY[cell.passivity]:
        bases = (Passivity, *bases)
    title = f"{_DAMPING_TITLES[cell.damping]}, {_FEEDBACK_TITLES[cell.feedback]}"
    title += ", passivity controllers" if PASSIVITY[cell.passivity] else ""
    attrs = {
        "name": name,
        "title": title,
        "adapts": cell.damping == "scheduled",
        "cell": cell,
        "__module__": __name__,
        "__doc__": f"Grid cell {name}: {title}.",
    }
    cls: type[Scheme] = type(name.replace("/", "_"), bases, attrs)
    return cls


def grid() -> dict[str, type[Scheme]]:
    """Return every cell of the grid, name -> class, in axis order (damping, feedback, passivity)."""
    return {cell_name(c): _compose(c) for c in (Cell(d, f, p) for d in DAMPINGS for f in FEEDBACKS for p in PASSIVITY)}
