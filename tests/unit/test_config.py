"""Profiles load and validate; bad files fail at start-up with one line and exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from bipedtele.config import ConfigError, load_config, profile_names

pytestmark = pytest.mark.timeout(60)


def _config_cmd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "config", *args],
        capture_output=True,
        text=True,
        timeout=30,
    )


def test_shipped_profiles_load() -> None:
    names = profile_names()
    for required in ("default", "localhost-delay", "intercontinental", "docker"):
        assert required in names
    for name in names:
        cfg = load_config(name)
        assert cfg.section("robot").id


def test_bad_value_exits_2_with_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("[clock]\ndelay_window_s = -1\n")
    res = _config_cmd("--config", str(bad))
    assert res.returncode == 2
    assert res.stdout == ""
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1
    line = lines[0]
    # file, key, value, allowed range
    assert str(bad) in line and "clock.delay_window_s" in line and "-1" in line
    assert "allowed: a number in [0.01, 60.0] s" in line


def test_bad_type_and_literal(tmp_path: Path) -> None:
    bad = tmp_path / "b.toml"
    bad.write_text('[network]\nmode = "mesh"\n')
    with pytest.raises(ConfigError) as exc:
        load_config(bad)
    msg = str(exc.value)
    assert "network.mode = 'mesh'" in msg and "'peer'" in msg and "'router'" in msg
    bad.write_text('[network]\nconnect = ["127.0.0.1:7447"]\n')
    with pytest.raises(ConfigError, match="PROTO/HOST:PORT"):
        load_config(bad)


def test_unknown_key_and_section(tmp_path: Path) -> None:
    f = tmp_path / "u.toml"
    f.write_text("[clock]\ndelay_windw_s = 1.0\n")
    res = _config_cmd("--config", str(f))
    assert res.returncode == 2
    assert "clock.delay_windw_s: unknown key" in res.stderr and "delay_window_s" in res.stderr
    f.write_text("[clok]\nmode = 'ntp'\n")
    with pytest.raises(ConfigError, match=r"unknown section \[clok\]; known sections: .*clock"):
        load_config(f)


def test_set_overrides(tmp_path: Path) -> None:
    cfg = load_config("default", ["clock.mode=ntp", "clock.delay_window_s=2.5", "robot.id=nao7"])
    assert cfg.section("clock").mode == "ntp"
    assert cfg.section("clock").delay_window_s == 2.5
    assert cfg.section("robot").id == "nao7"
    res = _config_cmd("--set", 'network.connect=["tcp/127.0.0.1:7447"]', "--set", "clock.mode=ntp")
    assert res.returncode == 0, res.stderr
    data = json.loads(res.stdout)
    assert data["network"]["connect"] == ["tcp/127.0.0.1:7447"]
    assert data["clock"]["mode"] == "ntp"
    res = _config_cmd("--set", "clock.ping_window=0")
    assert res.returncode == 2 and "clock.ping_window = 0" in res.stderr
    with pytest.raises(ConfigError, match=r"expected section\.key=value"):
        load_config("default", ["clockmode=ntp"])


def test_missing_file_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "none.toml")
    f = tmp_path / "t.toml"
    f.write_text("[clock\n")
    with pytest.raises(ConfigError, match="invalid TOML"):
        load_config(f)
    with pytest.raises(ConfigError, match=r"no such file or profile; profiles: .*default"):
        load_config("no-such-profile")
