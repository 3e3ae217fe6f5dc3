"""Every registered operator honours the Operator contract (Gymnasium-style checker)."""

from __future__ import annotations

import numpy as np
import pytest
from bipedtele.config import load_config
from bipedtele.leader.operator_check import OperatorContractError, check_operator
from bipedtele.leader.operators import (
    OPERATOR_REGISTRY,
    OPERATORS,
    Operator,
    make_operator,
    register_operator,
)
from bipedtele.messages import Feedback

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("name", sorted(OPERATOR_REGISTRY))
def test_every_registered_operator_meets_the_contract(name: str) -> None:
    cfg = load_config("localhost-delay")
    check_operator(lambda: make_operator(name, cfg, joystick=lambda: None))


def test_cli_choices_are_the_registry() -> None:
    assert set(OPERATORS) == set(OPERATOR_REGISTRY) >= {"scripted", "pilot", "browser"}


def test_registering_twice_is_refused() -> None:
    with pytest.raises(ValueError, match="already registered"):
        register_operator("pilot")(lambda ctx: make_operator("pilot", ctx.cfg))


class _Runaway(Operator):
    """An operator whose intent is not finite: the checker must say so."""

    name = "runaway"

    def intended_speed(self, t: float, feedback: Feedback | None) -> np.ndarray:
        return np.array([np.nan, 0.0])


class _Nameless(_Runaway):
    name = ""


def test_the_checker_catches_broken_operators() -> None:
    with pytest.raises(OperatorContractError, match="finite"):
        check_operator(lambda: _Runaway([160.0, 200.0]))
    with pytest.raises(OperatorContractError, match="name"):
        check_operator(lambda: _Nameless([160.0, 200.0]))
