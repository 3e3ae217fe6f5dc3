"""Contract checker for :class:`~bipedtele.leader.operator.Operator` implementations.

``check_operator(factory)`` drives a *fresh* operator the way the leader loop and the
simulated device use it (``update`` at the command rate, ``hand_force`` at every
integration step, ``observe_sample``, ``progress``) and raises :class:`OperatorContractError`
naming the first broken rule, like Gymnasium's ``check_env``. The tests run it over every
registered operator.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from bipedtele.leader.operator import Operator
from bipedtele.link.messages import Feedback
from bipedtele.telemetry import LeaderSample

__all__ = ["OperatorContractError", "check_operator"]


class OperatorContractError(AssertionError):
    """An operator broke the Operator contract; the message says which rule."""


def _expect(cond: bool, rule: str) -> None:
    if not cond:
        raise OperatorContractError(rule)


def _feedback(t: float, x_m: float) -> Feedback:
    return Feedback(
        t=t,
        seq=int(t * 100) + 1,
        eta=[2.0, 0.0],
        z_r=[2.0, 0.0],
        pose=[x_m, 0.0, 0.0],
        sonar=[2.0, 2.0],
    )


def check_operator(factory: Callable[[], Operator], *, steps: int = 300, dt_s: float = 0.01) -> None:
    """Check the Operator contract on a fresh operator.

    Parameters
    ----------
    factory : callable
        Returns a new operator.
    steps : int
        Command updates to run.
    dt_s : float
        Period of the updates [s].

    Raises
    ------
    OperatorContractError
        The first rule the operator broke.
    """
    op = factory()
    _expect(isinstance(op, Operator), "the factory must return an Operator")
    _expect(bool(op.name), "an operator must have a non-empty class attribute `name`")
    lim = op.workspace_m
    x = np.zeros(2)
    t = 0.0
    for i in range(steps):
        fb = None if i < 5 else _feedback(t, 0.02 * t)
        op.update(t, fb)
        intended = np.asarray(op.intended, dtype=float)
        _expect(intended.shape == (2,), "update() must leave `intended` with shape (2,)")
        _expect(bool(np.all(np.isfinite(intended))), "intended speeds must be finite")
        target = np.asarray(op.hand.target, dtype=float)
        _expect(bool(np.all(np.abs(target) <= lim + 1e-12)), f"hand target {target} outside the workspace +-{lim} m")
        f = np.asarray(op.hand_force(t, x, np.zeros(2)), dtype=float)
        _expect(f.shape == (2,) and bool(np.all(np.isfinite(f))), "hand_force() must return 2 finite forces [N]")
        _expect(bool(np.all(np.abs(f) <= op.hand.f_max + 1e-9)), "hand_force() must stay within the hand's strength")
        op.observe_sample(
            LeaderSample(
                t=t,
                t_device=t,
                ref_v=float(intended[0]),
                ref_w=float(intended[1]),
                enable=True,
                h1_ms=300.0,
                h2_ms=300.0,
                delay_ms=600.0,
            )
        )
        x = np.clip(x + 0.001 * np.sign(target - x), -lim, lim)
        t += dt_s
    done = op.done
    _expect(isinstance(done, bool), "done must be a bool")
    prog = op.progress()
    _expect(isinstance(prog, dict), "progress() must return a dict")
    _expect(prog.get("operator") == op.name, "progress()['operator'] must be the operator's name")
    _expect(prog.get("done") is done, "progress()['done'] must equal done")
    _expect(all(isinstance(k, str) for k in prog), "progress() keys must be strings")
    _expect(
        all(not isinstance(v, float) or math.isfinite(v) for v in prog.values()),
        "progress() numbers must be finite",
    )
