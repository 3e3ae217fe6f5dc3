"""Typed access to the profile (issue 22): ``cfg.get(LeaderConfig)`` is a ``LeaderConfig``.

``Config.section(name)`` returns ``Any``; 41 call sites read the profile that way, so a
misspelt field or a wrong type passed mypy (``cameras`` was ``list[str]`` where the video
wanted the two camera names: found once typed). The product reads each section through
its class; by name only where the class belongs to another role (the leader's pilot reads
the follower's ``[world]``) or to no one in particular (``bipedtele config``).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError, load_config
from bipedtele.config.sections import NetworkConfig
from bipedtele.control.config import ControlConfig
from bipedtele.follower.config import FollowerConfig
from bipedtele.leader.config import LeaderConfig

pytestmark = pytest.mark.timeout(60)

ROOT = Path(__file__).resolve().parents[2]


def test_get_returns_the_section_of_that_class() -> None:
    cfg = load_config("default", ['leader.operator="pilot"', "control.D=[1.5, 1.2]"])
    assert isinstance(cfg.get(LeaderConfig), LeaderConfig) and cfg.get(LeaderConfig).operator == "pilot"
    assert cfg.get(ControlConfig).D == [1.5, 1.2]
    assert cfg.get(NetworkConfig) is cfg.section("network")
    assert cfg.get(FollowerConfig).cameras == ["scene", "head"]


def test_a_class_that_is_no_section_is_named() -> None:
    class NotASection:
        pass

    with pytest.raises(ConfigError, match=r"no section of class NotASection; known: .*leader"):
        load_config("default").get(NotASection)


def test_the_product_reads_no_section_by_name() -> None:
    """``.section("...")`` is the untyped way: none in the product's code (the docstring of
    ``Config`` shows it once)."""
    found = []
    for part in ("common", "leader", "follower", "studies", "bench", "docker"):
        for path in sorted((ROOT / part).rglob("*.py")):
            for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if re.search(r"\.section\(\"[a-z_]+\"\)", line) and not line.lstrip().startswith(">>>"):
                    found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert found == []
