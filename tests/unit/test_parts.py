"""The part registries (common/parts.py): entry points are the only list, and a wrong one is named."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from bipedtele.config.profile import load_config
from bipedtele.follower.robot import ROBOTS, RobotPart, make_robot, robot_names
from bipedtele.leader.device import DEVICES, DevicePart
from bipedtele.leader.operator import OPERATORS, OperatorPart
from bipedtele.parts import PART_GROUPS, PartError, Parts, part_sections

pytestmark = pytest.mark.timeout(60)

_MODULE = """
from bipedtele.follower.robot import RobotPart
from bipedtele.leader.device import DevicePart

def _never(**kwargs):
    raise AssertionError("not built in this test")

RENAMED = RobotPart(name="someone-else", doc="a part registered under another name", build=_never)
DEVICE = DevicePart(name="wrong-kind", doc="a device registered as a robot", build=_never)
SIM_AGAIN = RobotPart(name="sim", doc="a second sim", build=_never)
NOT_A_PART = 42
"""


def _dist(tmp: Path, lines: str) -> Path:
    (tmp / "broken_parts.py").write_text(_MODULE)
    info = tmp / "broken_parts-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-parts\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(lines)
    return tmp


def test_every_built_in_part_is_found_by_its_entry_point_and_named_as_it() -> None:
    for registry, part_type in ((ROBOTS, RobotPart), (DEVICES, DevicePart), (OPERATORS, OperatorPart)):
        assert registry.group == PART_GROUPS[registry.kind]
        for name in registry.names():
            part = registry.get(name)
            assert isinstance(part, part_type) and part.name == name
            assert part.doc and "\n" not in part.doc
    cfg = load_config("default")
    for name in robot_names() + DEVICES.names():
        part = ROBOTS.get(name) if name in ROBOTS else DEVICES.get(name)
        assert part.section is None or part.section in cfg.sections, (name, part.section)
    assert {"sim", "naoqi", "joystick", "falcon"} <= set(part_sections())


def test_an_unknown_name_lists_the_allowed_ones() -> None:
    with pytest.raises(ValueError, match=r"robot 'nope': allowed: naoqi, sim"):
        make_robot("nope")


def test_wrong_entry_points_are_named(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    lines = (
        "[bipedtele.robots]\nrenamed = broken_parts:RENAMED\nwrong-kind = broken_parts:DEVICE\n"
        "not-a-part = broken_parts:NOT_A_PART\nsim = broken_parts:SIM_AGAIN\n"
    )
    monkeypatch.syspath_prepend(str(_dist(tmp_path, lines)))
    robots = Parts("robot", PART_GROUPS["robot"], RobotPart)  # a fresh registry: nothing cached
    assert {"renamed", "wrong-kind", "not-a-part", "sim"} <= set(robots.names())
    with pytest.raises(PartError, match="names the robot 'someone-else'"):
        robots.get("renamed")
    with pytest.raises(PartError, match="is not a RobotPart"):
        robots.get("wrong-kind")
    with pytest.raises(PartError, match="is not a RobotPart"):
        robots.get("not-a-part")
    with pytest.raises(
        PartError, match=re.escape("registered twice: bipedtele.follower.sim.config:PART, broken_parts:SIM_AGAIN")
    ):
        robots.get("sim")
