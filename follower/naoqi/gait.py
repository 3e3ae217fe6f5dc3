"""From a walk command (speeds, walking cycle T) to ALMotion's move config.

NAO's walk engine chooses its step length from the asked speed and its step period from
the normalised ``MaxStepFrequency`` in [0, 1]: 0 is the longest step period ``P_max``, 1
the shortest ``P_min``, linear in between. A walking cycle is two steps, so the cycle T
asks for a step period ``T / 2`` and

    MaxStepFrequency = (P_max - T/2) / (P_max - P_min)        (clipped to [0, 1]).

At step period P with steps no longer than ``MaxStepX`` the forward speed cannot exceed
``MaxStepX / P``, and the turn rate cannot exceed ``MaxStepTheta / P``; the speeds sent
are clipped to these so that the command returned is what NAO will really do.
"""

from __future__ import annotations

from dataclasses import dataclass

from bipedtele.follower.naoqi.config import NaoqiConfig
from bipedtele.follower.robot import WalkCommand, WalkLimits

__all__ = ["MoveConfig", "move_config_for", "walk_limits"]


@dataclass(frozen=True)
class MoveConfig:
    """The ALMotion ``move`` call for one command.

    Attributes
    ----------
    x_m_s, y_m_s : float
        Forward and lateral speed [m/s] (FRAME_ROBOT).
    theta_rad_s : float
        Turn rate [rad/s], positive counter-clockwise.
    step_frequency : float
        Normalised ``MaxStepFrequency`` in [0, 1].
    step_period_s : float
        Step period realised by ``step_frequency`` [s].
    max_step_x_m, max_step_y_m : float
        ``MaxStepX``, ``MaxStepY`` [m].
    max_step_theta_rad : float
        ``MaxStepTheta`` [rad].
    step_height_m : float
        ``StepHeight`` [m].
    """

    x_m_s: float
    y_m_s: float
    theta_rad_s: float
    step_frequency: float
    step_period_s: float
    max_step_x_m: float
    max_step_y_m: float
    max_step_theta_rad: float
    step_height_m: float

    def as_naoqi(self) -> list[list[object]]:
        """Return the move config as ALMotion takes it: ``[[name, value], ...]``."""
        return [
            ["MaxStepX", self.max_step_x_m],
            ["MaxStepY", self.max_step_y_m],
            ["MaxStepTheta", self.max_step_theta_rad],
            ["MaxStepFrequency", self.step_frequency],
            ["StepHeight", self.step_height_m],
        ]


def walk_limits(cfg: NaoqiConfig) -> WalkLimits:
    """Return the :class:`WalkLimits` of a NAO with settings ``cfg``."""
    return WalkLimits(
        max_forward_m_s=cfg.max_forward_m_s,
        max_turn_rad_s=cfg.max_turn_rad_s,
        cycle_s=cfg.cycle_range_s,
    )


def move_config_for(cmd: WalkCommand, cfg: NaoqiConfig) -> tuple[MoveConfig, WalkCommand]:
    """Return the move call realising ``cmd`` on NAO, and the command it realises.

    Parameters
    ----------
    cmd : WalkCommand
        Asked command (SI units; clamped here to the NAO's limits first).
    cfg : NaoqiConfig
        Step limits and step-period range.

    Returns
    -------
    (MoveConfig, WalkCommand)
        What to send, and the command it really asks for: speeds within the step limits
        at the realised step period, cycle ``2 * step period``.
    """
    c = cmd.clamped(walk_limits(cfg))
    p_min, p_max = cfg.min_step_period_s, cfg.max_step_period_s
    freq = min(1.0, max(0.0, (p_max - c.cycle_s / 2.0) / (p_max - p_min)))
    period = p_max - freq * (p_max - p_min)
    v_max = cfg.max_step_x_m / period
    w_max = cfg.max_step_theta_rad / period
    v = min(v_max, max(-v_max, c.forward_m_s))
    w = min(w_max, max(-w_max, c.turn_rad_s))
    move = MoveConfig(
        x_m_s=v,
        y_m_s=0.0,
        theta_rad_s=w,
        step_frequency=freq,
        step_period_s=period,
        max_step_x_m=cfg.max_step_x_m,
        max_step_y_m=cfg.max_step_y_m,
        max_step_theta_rad=cfg.max_step_theta_rad,
        step_height_m=cfg.step_height_m,
    )
    sent = WalkCommand(forward_m_s=v, turn_rad_s=w, cycle_s=2.0 * period, eps_s=c.eps_s)
    return move, sent
