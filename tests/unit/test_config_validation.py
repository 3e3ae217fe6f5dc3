"""Section validation: every field type and range, and the exact one-line error for each.

The expected messages were taken from the hand-written coercion that msgspec replaced
(``FILE: [section].key = VALUE: allowed: ...``), so the two behave the same.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pytest
from bipedtele.config.profile import Config, ConfigError, load_config, param, parse_section, resolve_section

pytestmark = pytest.mark.timeout(30)


@dataclass(frozen=True)
class _Leg:
    shape: Literal["box", "cylinder"] = param("box")
    size: list[float] = param(default_factory=lambda: [1.0], lo=0.001, hi=50.0, unit="m")

    def __post_init__(self) -> None:
        if self.shape == "cylinder" and len(self.size) != 2:
            raise ValueError(f"size = {self.size!r}: allowed: 2 numbers for a cylinder")


@dataclass(frozen=True)
class _All:
    rate: float = param(10.0, lo=0.1, hi=600.0, unit="Hz")
    gain: float = param(1.0, lo=0.0, lo_open=True)
    cap: float = param(1.0, hi=10.0)
    free: float = param(0.0, unit="s")
    low: float = param(0.0, lo=0.0, unit="m")
    count: int = param(16, lo=1, hi=1024)
    port: int = param(0, lo=0.0, hi=65535)
    flag: bool = param(False)
    name: str = param("x")
    mode: Literal["a", "b"] = param("a")
    many: list[float] = param(default_factory=list, lo=-1.0, hi=1.0, unit="m")
    words: list[str] = param(default_factory=list)
    grid: list[list[float]] = param(default_factory=list)
    legs: list[_Leg] = param(default_factory=list)
    maybe: float | None = param(None, lo=0.0)

    def __post_init__(self) -> None:
        if self.flag and self.name == "x":
            raise ValueError("flag and name: allowed: a name other than 'x' when flag is set")


W = "f.toml: all"

BAD = [
    ({"rate": -1}, "f.toml: all.rate = -1: allowed: a number in [0.1, 600.0] Hz"),
    ({"rate": 601.0}, "f.toml: all.rate = 601.0: allowed: a number in [0.1, 600.0] Hz"),
    ({"rate": "fast"}, "f.toml: all.rate = 'fast': allowed: a number in [0.1, 600.0] Hz"),
    ({"rate": True}, "f.toml: all.rate = True: allowed: a number in [0.1, 600.0] Hz"),
    ({"rate": math.nan}, "f.toml: all.rate = nan: allowed: a number in [0.1, 600.0] Hz"),
    ({"gain": 0}, "f.toml: all.gain = 0: allowed: a number > 0.0"),
    ({"gain": math.inf}, "f.toml: all.gain = inf: allowed: a number > 0.0"),
    ({"cap": 11}, "f.toml: all.cap = 11: allowed: a number <= 10.0"),
    ({"free": math.nan}, "f.toml: all.free = nan: allowed: a number s"),
    ({"free": -math.inf}, "f.toml: all.free = -inf: allowed: a number s"),
    ({"free": [1]}, "f.toml: all.free = [1]: allowed: a number s"),
    ({"low": -0.5}, "f.toml: all.low = -0.5: allowed: a number >= 0.0 m"),
    ({"count": 0}, "f.toml: all.count = 0: allowed: a number in [1, 1024]"),
    ({"count": 2048.0}, "f.toml: all.count = 2048: allowed: a number in [1, 1024]"),
    ({"count": 2.5}, "f.toml: all.count = 2.5: allowed: an integer"),
    ({"count": "3"}, "f.toml: all.count = '3': allowed: an integer"),
    ({"count": True}, "f.toml: all.count = True: allowed: an integer"),
    ({"count": math.inf}, "f.toml: all.count = inf: allowed: an integer"),
    ({"port": 70000}, "f.toml: all.port = 70000: allowed: a number in [0.0, 65535]"),
    ({"flag": 1}, "f.toml: all.flag = 1: allowed: true or false"),
    ({"flag": "yes"}, "f.toml: all.flag = 'yes': allowed: true or false"),
    ({"name": 3}, "f.toml: all.name = 3: allowed: a string"),
    ({"mode": "c"}, "f.toml: all.mode = 'c': allowed: one of 'a', 'b'"),
    ({"mode": 1}, "f.toml: all.mode = 1: allowed: one of 'a', 'b'"),
    ({"many": 0.5}, "f.toml: all.many = 0.5: allowed: a list of a number"),
    ({"many": [0.5, 2.0]}, "f.toml: all.many[1] = 2.0: allowed: a number in [-1.0, 1.0] m"),
    ({"many": [0.5, math.nan]}, "f.toml: all.many[1] = nan: allowed: a number in [-1.0, 1.0] m"),
    ({"many": ["a"]}, "f.toml: all.many[0] = 'a': allowed: a number in [-1.0, 1.0] m"),
    ({"words": ["a", 2]}, "f.toml: all.words[1] = 2: allowed: a string"),
    ({"words": "a"}, "f.toml: all.words = 'a': allowed: a list of a string"),
    ({"grid": [[1.0], 2.0]}, "f.toml: all.grid[1] = 2.0: allowed: a list of a number"),
    ({"grid": [[1.0], [2.0, math.inf]]}, "f.toml: all.grid[1][1] = inf: allowed: a number"),
    ({"grid": [[1.0], [2.0, "x"]]}, "f.toml: all.grid[1][1] = 'x': allowed: a number"),
    ({"legs": {"shape": "box"}}, "f.toml: all.legs = {'shape': 'box'}: allowed: a list of _Leg"),
    ({"legs": [{"shape": "box"}, 3]}, "f.toml: all.legs[1] = 3: allowed: a table of _Leg fields"),
    ({"legs": [{"shape": "cone"}]}, "f.toml: all.legs[0].shape = 'cone': allowed: one of 'box', 'cylinder'"),
    ({"legs": [{"size": [0.0]}]}, "f.toml: all.legs[0].size[0] = 0.0: allowed: a number in [0.001, 50.0] m"),
    ({"legs": [{}, {"sise": [1.0]}]}, "f.toml: all.legs[1].sise: unknown key; allowed keys: shape, size"),
    (
        {"legs": [{"shape": "cylinder", "size": [1.0]}]},
        "f.toml: all.legs[0]: size = [1.0]: allowed: 2 numbers for a cylinder",
    ),
    ({"maybe": -1.0}, "f.toml: all.maybe = -1.0: allowed: a number or absent"),
    ({"maybe": "x"}, "f.toml: all.maybe = 'x': allowed: a number or absent"),
    (
        {"rate": 1.0, "colour": "red"},
        "f.toml: all.colour: unknown key; allowed keys: cap, count, flag, free, gain, grid, legs, "
        "low, many, maybe, mode, name, port, rate, words",
    ),
    (
        {"flag": True},
        "f.toml: all: flag and name: allowed: a name other than 'x' when flag is set",
    ),
    ({"mode": "a" * 80}, "f.toml: all.mode = " + repr("a" * 80)[:57] + "...: allowed: one of 'a', 'b'"),
]


@pytest.mark.parametrize(("data", "message"), BAD, ids=[m.split(" = ")[0][len(W) :] for _, m in BAD])
def test_bad_value_gives_the_one_line_message(data: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError) as exc:
        parse_section(_All, data, W)
    assert str(exc.value) == message
    assert "\n" not in str(exc.value)


def test_the_first_bad_key_in_file_order_is_named() -> None:
    with pytest.raises(ConfigError, match=r"all\.count = 0:"):
        parse_section(_All, {"count": 0, "rate": -1}, W)
    with pytest.raises(ConfigError, match=r"all\.rate = -1:"):
        parse_section(_All, {"rate": -1, "count": 0}, W)


def test_good_values_convert_like_the_file_means() -> None:
    got = parse_section(
        _All,
        {
            "rate": 600,
            "gain": 1e-9,
            "count": 2.0,
            "port": 65535,
            "free": -1e300,
            "many": [-1, 1.0],
            "words": ["a"],
            "grid": [[1, 2.5], []],
            "legs": [{"shape": "cylinder", "size": [1, 2]}, {}],
            "mode": "b",
            "flag": True,
            "name": "y",
            "maybe": 2,
        },
        W,
    )
    assert isinstance(got, _All)
    assert got.rate == 600.0 and isinstance(got.rate, float)
    assert got.count == 2 and isinstance(got.count, int)  # a whole float is taken as an integer
    assert got.port == 65535 and isinstance(got.port, int)
    assert got.many == [-1.0, 1.0] and all(isinstance(v, float) for v in got.many)
    assert got.grid == [[1.0, 2.5], []] and isinstance(got.grid[0][0], float)
    assert got.legs == [_Leg("cylinder", [1.0, 2.0]), _Leg()]
    assert isinstance(got.legs[0], _Leg) and isinstance(got.legs[0].size[0], float)
    assert got.maybe == 2.0 and isinstance(got.maybe, float)
    assert got.gain == 1e-9 and got.free == -1e300
    # keys not given keep their defaults (including default factories)
    assert parse_section(_All, {}, W) == _All()
    assert parse_section(_All, {}, W).legs is not _All().legs


def test_overrides_through_resolve_section_and_replace(tmp_path: Path) -> None:
    base = _All(count=3, legs=[_Leg("box", [2.0])])
    got = resolve_section(base, _All, "all", {"rate": 5, "maybe": None})
    assert got.rate == 5.0 and got.count == 3 and got.legs == [_Leg("box", [2.0])] and got.maybe is None
    with pytest.raises(ConfigError, match=r"^all\.rate = 0: allowed: a number in \[0\.1, 600\.0\] Hz$"):
        resolve_section(base, _All, "all", {"rate": 0})
    with pytest.raises(ConfigError, match=r"^all\.nope: unknown key; allowed keys: cap, "):
        resolve_section(base, _All, "all", {"nope": 1})
    (tmp_path / "p.toml").write_text("[all]\ncount = 4\n[[all.legs]]\nshape = 'cylinder'\nsize = [1, 1]\n")
    cfg = load_config(tmp_path / "p.toml", extra_sections={"all": _All})
    assert isinstance(cfg, Config) and cfg.section("all").legs == [_Leg("cylinder", [1.0, 1.0])]
    changed = cfg.replace("all", count=9)
    assert changed.section("all").count == 9 and changed.section("all").legs == cfg.section("all").legs
    with pytest.raises(ConfigError, match=r"p\.toml: all\.count = 0: allowed: a number in \[1, 1024\]$"):
        cfg.replace("all", count=0)


def test_toml_nan_and_inf_are_refused(tmp_path: Path) -> None:
    f = tmp_path / "n.toml"
    for text, key in (("free = nan", "free"), ("many = [0.0, inf]", "many[1]"), ("count = -inf", "count")):
        f.write_text(f"[all]\n{text}\n")
        with pytest.raises(ConfigError, match=re.escape(f"all.{key} = ") + "-?(nan|inf): allowed: "):
            load_config(f, extra_sections={"all": _All})
