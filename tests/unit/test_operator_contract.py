"""Every registered operator honours the Operator contract (Gymnasium-style checker)."""

from __future__ import annotations

import numpy as np
import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.leader.operator import Operator, make_operator, operator_names
from bipedtele.leader.operator_check import OperatorContractError, check_operator
from bipedtele.link.messages import Feedback

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("name", operator_names())
def test_every_registered_operator_meets_the_contract(name: str) -> None:
    cfg = load_config("localhost-delay")
    check_operator(lambda: make_operator(name, cfg, joystick=lambda: None))
    assert make_operator(name, cfg, joystick=lambda: None).name == name


def test_the_built_in_operators_are_registered() -> None:
    assert set(operator_names()) >= {"scripted", "pilot", "browser"}


def test_an_unknown_operator_in_the_profile_names_the_allowed_ones() -> None:
    with pytest.raises(ConfigError, match=r"operator.*'nope'.*allowed: 'browser', 'pilot', 'scripted'"):
        load_config("default", ['leader.operator="nope"'])


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
