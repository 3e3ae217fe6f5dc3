"""The calibration's reset factor lies in the reduced model's domain (0, 1]."""

from __future__ import annotations

import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.follower.sim.calibrate import model_dp


def test_measured_dp_above_one_is_no_loss_in_the_model() -> None:
    # The gait that walks at the commanded ground speed measured a median of 1.041: the impact
    # costs no speed. The reset (22) only loses speed, and the config accepts (0, 1].
    assert model_dp(1.0408) == 1.0
    assert model_dp(0.938) == pytest.approx(0.938)
    # what `calibrate` prints after "use it:" loads; the raw median does not
    cfg = load_config("default", [f"control.calibrated_dp={model_dp(1.0408):.4f}"])
    assert cfg.section("control").calibrated_dp == 1.0
    with pytest.raises(ConfigError, match="calibrated_dp"):
        load_config("default", ["control.calibrated_dp=1.0408"])
    with pytest.raises(ValueError, match="did not walk forward"):
        model_dp(-0.2)
