"""The comparison's delay regimes and settings: what `bipedtele compare` runs its schemes over.

A regime is a delay model per direction, a scale on it, an optional step and message loss
(:class:`Regime`); :class:`CompareParams` holds the comparison's settings that are not
controller parameters (docs/schemes.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from bipedtele.control.reduced import StudyParams

__all__ = [
    "ALPHA",
    "EQUIVALENCE_MARGINS",
    "MARGIN_SCALES",
    "METRICS",
    "REGIMES",
    "RELEASED_MARGIN_M_S",
    "CompareParams",
    "Regime",
]


@dataclass(frozen=True)
class Regime:
    """A delay regime: delay models, a scale on them, an optional step, message loss.

    Attributes
    ----------
    name, description : str
        Table label and one line.
    h1, h2 : str
        Delay-model specs (:mod:`bipedtele.link.delaymodels`) of each direction.
    scale : float
        Factor on both delays.
    step_s : tuple of float or None
        ``(before, after)`` [s]: both delays constant, jumping mid-run (``h1``, ``h2`` unused).
    loss : float
        Probability that a message is lost, each direction, independently.
    """

    name: str
    description: str
    h1: str = "trace:intercontinental:h1"
    h2: str = "trace:intercontinental:h2"
    scale: float = 1.0
    step_s: tuple[float, float] | None = None
    loss: float = 0.0


#: The regimes of the default set. ``trace`` carries the 5 % loss that a separate lossless
#: regime used to lack: with and without it every cell's errors agree within 0.003 cm/s and
#: deg/s (paired, TOST-equivalent within the margins; docs/schemes.md), so the two were one.
REGIMES: tuple[Regime, ...] = (
    Regime(
        "trace",
        "the shipped intercontinental trace (130-370 ms, time-varying, asymmetric), 5 % of the messages lost each way",
        loss=0.05,
    ),
    Regime("trace-x2", "the shipped trace, delays doubled", scale=2.0),
    Regime("trace-x4", "the shipped trace, delays x4 (0.5-1.5 s)", scale=4.0),
    Regime("satellite", "1.5 s +- 0.2 s each way", "uniform:1500ms:200ms", "uniform:1500ms:200ms"),
    Regime("congested-satellite", "3.5 s +- 0.3 s each way", "uniform:3500ms:300ms", "uniform:3500ms:300ms"),
    Regime("step", "0.3 s each way, 3 s from mid-run on", step_s=(0.3, 3.0)),
)

#: Delay scales of the shipped trace at which the operator lets go of the handle (x0: the
#: no-delay reference); the stability map over delay itself is ``bipedtele margin``.
MARGIN_SCALES: tuple[float, ...] = (0.0, 1.0, 4.0, 16.0)

#: Family-wise error rate of every family of tests (Holm within the family).
ALPHA = 0.05
#: Equivalence margins of the TOST, per metric, stated before the runs [the metric's unit:
#: cm/s forward, deg/s turn, N for the force error and the effort].
EQUIVALENCE_MARGINS: dict[str, float] = {
    "forward_error": 0.1,
    "turn_error": 0.3,
    "forward_intent_error": 0.1,
    "turn_intent_error": 0.3,
    "forward_force_error": 0.1,
    "turn_force_error": 0.1,
    "forward_effort": 0.1,
    "turn_effort": 0.1,
}
#: Equivalence margin of the released handle's RMS speed [m/s] (0.5 mm/s).
RELEASED_MARGIN_M_S = 0.0005

_CHANNEL_METRICS = ("error", "intent_error", "force_error", "effort", "po_leader", "po_follower")
#: Every metric reported per run (``unstable`` is a count, not a mean).
METRICS: tuple[str, ...] = (
    *(f"{c}_{m}" for m in _CHANNEL_METRICS for c in ("forward", "turn")),
    "peak",
)


@dataclass(frozen=True)
class CompareParams:
    """Settings of a comparison that are not controller parameters.

    Attributes
    ----------
    study : StudyParams
        Operator, handle, period and duration (the study's).
    unstable_factor : float
        A run is unstable when the robot's speed exceeds this times the largest intended one.
    release_fraction : float
        In the margin runs, the operator lets go of the handle at this fraction of the run.
    oscillation_m_s : float
        A margin run oscillates when the released handle's RMS speed over the run's last
        quarter exceeds this [m/s] on either axis (2 mm/s: 0.3 cm/s of forward command).
    """

    study: StudyParams = field(default_factory=StudyParams)
    unstable_factor: float = 3.0
    release_fraction: float = 0.5
    oscillation_m_s: float = 0.002
