"""What the follower loop reports: its telemetry and the Feedback it publishes.

:class:`FollowerTelemetry` is what the loop did in its last tick; :func:`feedback_message`
turns it into the :class:`~bipedtele.link.messages.Feedback` the leader receives (every value
finite and within the message's bounds, docs/network.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from bipedtele.follower.robot import RobotObservation, WalkCommand
from bipedtele.link.messages import MAX_SPEED, Feedback

__all__ = ["FollowerTelemetry", "feedback_message", "pair"]


@dataclass
class FollowerTelemetry:
    """What the loop did in its last tick (for feedback, recording and tests)."""

    t: float = 0.0
    state: str = "starting"
    ref: np.ndarray = field(default_factory=lambda: np.zeros(2))
    eta_cmd: np.ndarray = field(default_factory=lambda: np.zeros(2))
    eta_meas: np.ndarray = field(default_factory=lambda: np.zeros(2))
    z_r: np.ndarray = field(default_factory=lambda: np.zeros(2))
    z_e: np.ndarray = field(default_factory=lambda: np.zeros(2))
    f_v: np.ndarray = field(default_factory=lambda: np.zeros(2))
    h1_s: float = 0.0
    h2_s: float = 0.0
    s_e: np.ndarray = field(default_factory=lambda: np.zeros(2))
    s_r: np.ndarray = field(default_factory=lambda: np.zeros(2))
    T: float = 1.0
    eps: float = 0.1
    sent: WalkCommand | None = None
    obs: RobotObservation | None = None


def feedback_message(
    tel: FollowerTelemetry, obs: RobotObservation, sid: int, seq: int, now: float, cmd_seq: int, wave: Any, energy: Any
) -> Feedback:
    """Return the Feedback of the tick ``tel`` with the observation ``obs`` at ``now`` [s].

    ``wave`` and ``energy`` are the scheme's outgoing port values; ``cmd_seq`` the command
    it acknowledges (0: none yet).
    """
    lim = MAX_SPEED
    return Feedback(
        sid=sid,
        seq=seq,
        t=now,
        z_e=pair(tel.z_e, lim),
        z_r=pair(tel.z_r, lim),
        eta=pair(tel.eta_meas, lim),
        ref=pair(tel.ref, lim),
        pose=[float(v) for v in obs.pose],
        sonar=[float(min(max(v, 0.0), 100.0)) for v in obs.sonar_m],
        f_v=pair(tel.f_v, lim),
        h1_s=float(min(max(tel.h1_s, 0.0), 60.0)),
        s_e=[float(v) for v in tel.s_e],
        s_r=[float(v) for v in tel.s_r],
        T=float(tel.T),
        eps=float(tel.eps),
        state=tel.state,
        cmd_seq=cmd_seq,
        wave=wave,
        energy=energy,
    )


def pair(v: np.ndarray, lim: float) -> list[float]:
    """Return ``v`` as two finite floats within ``[-lim, lim]`` (NaN: 0)."""
    a = np.nan_to_num(np.asarray(v, dtype=float), nan=0.0, posinf=lim, neginf=-lim)
    return [float(x) for x in np.clip(a, -lim, lim)]
