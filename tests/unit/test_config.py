"""Profiles load and validate; bad files fail at start-up with one line and exit code 2."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError, load_config, param, profile_names

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


# ----------------------------------------------------------------- profile-relative paths


@dataclass(frozen=True)
class _Inner:
    cert: str = param("", path=True, doc="a file")
    label: str = param("", doc="not a path")


@dataclass(frozen=True)
class _Files:
    ca: str = param("", path=True, doc="a file")
    many: list[str] = param(default_factory=list, path=True, doc="files")
    note: str = param("", doc="not a path")
    inner: list[_Inner] = param(default_factory=list, doc="nested tables")
    api_credential: str = param("", secret=True, doc="a secret with an innocent name")
    token: str = param("", doc="a secret by its name")
    token_file: str = param("", path=True, doc="where the token is: not a secret")


_EXTRA = {"files": _Files}


def test_profile_file_paths_are_relative_to_its_folder(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    host = tmp_path / "copied" / "robot"
    (host / "certs").mkdir(parents=True)
    (host / "certs" / "ca.pem").write_text("ca")
    absolute = tmp_path / "abs.pem"
    (host / "bipedtele.toml").write_text(
        "[files]\n"
        'ca = "certs/ca.pem"\n'
        f'many = ["certs/a.pem", "{absolute}", ""]\n'
        'note = "certs/not-a-path"\n'
        '[[files.inner]]\ncert = "../sibling/x.pem"\nlabel = "certs/y"\n'
    )
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    for given in (host / "bipedtele.toml", Path("..", "copied", "robot", "bipedtele.toml")):
        f = load_config(given, extra_sections=_EXTRA).section("files")
        assert Path(f.ca).resolve() == (host / "certs" / "ca.pem").resolve()
        assert Path(f.ca).read_text() == "ca"  # readable from the other working folder
        assert Path(f.many[0]).resolve() == (host / "certs" / "a.pem").resolve()
        assert f.many[1:] == [str(absolute), ""]  # absolute and empty: unchanged
        assert f.note == "certs/not-a-path"  # fields that are not paths: unchanged
        assert Path(f.inner[0].cert).resolve() == (tmp_path / "copied" / "sibling" / "x.pem").resolve()
        assert f.inner[0].label == "certs/y"


def test_override_and_shipped_profile_paths_stay_relative_to_the_working_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    (tmp_path / "p.toml").write_text('[files]\nca = "certs/ca.pem"\n')
    monkeypatch.chdir(tmp_path)
    cfg = load_config(tmp_path / "p.toml", ["files.many=['mine/a.pem']"], extra_sections=_EXTRA)
    assert cfg.section("files").many == ["mine/a.pem"]
    cfg = load_config(tmp_path / "p.toml", ["files.ca=mine/ca.pem"], extra_sections=_EXTRA)
    assert cfg.section("files").ca == "mine/ca.pem"  # the override replaces the file's value
    net = load_config("intercontinental").section("network")
    assert net.tls_root_ca == "certs/ca.pem"


def test_network_paths_in_a_profile_file_follow_the_file(tmp_path: Path) -> None:
    """The real [network] files (marked path=True in common/config/sections.py) follow the profile."""
    from bipedtele.config.sections import NetworkConfig

    marked = {f.name for f in dataclasses.fields(NetworkConfig) if f.metadata.get("path")}
    assert {"tls_root_ca", "tls_cert", "tls_key", "password_file", "credentials_file"} <= marked
    folder = tmp_path / "operator"
    folder.mkdir()
    (folder / "p.toml").write_text('[network]\ntls_root_ca = "certs/ca.pem"\npassword_file = "secrets/leader.pw"\n')
    net = load_config(folder / "p.toml").section("network")
    assert net.tls_root_ca == str(folder / "certs" / "ca.pem")
    assert net.password_file == str(folder / "secrets" / "leader.pw")


# ----------------------------------------------------------------- redaction


def test_to_dict_redacts_secrets_by_default(tmp_path: Path) -> None:
    (tmp_path / "p.toml").write_text('[files]\napi_credential = "c0ffee"\ntoken = "t0ken"\ntoken_file = "secrets/t"\n')
    cfg = load_config(tmp_path / "p.toml", ['network.password="hunter2"'], extra_sections=_EXTRA)
    shown = cfg.to_dict()
    assert shown["files"]["api_credential"] == "***"  # marked secret=True
    assert shown["files"]["token"] == "***"  # named like a secret
    assert shown["files"]["token_file"] == str(tmp_path / "secrets" / "t")  # a path, kept
    assert shown["network"]["password"] == "***"
    assert shown["network"]["user"] == ""  # not a secret, shown
    for secret in ("c0ffee", "t0ken", "hunter2"):
        assert secret not in json.dumps(shown)
    unset = load_config("default").to_dict()
    assert unset["network"]["password"] == ""  # nothing to hide: shown as unset
    raw = cfg.to_dict(redact=False)
    assert raw["network"]["password"] == "hunter2" and raw["files"]["api_credential"] == "c0ffee"


def test_config_command_never_prints_an_inline_password() -> None:
    """Issue 10 item 11: a password set inline was printed by ``bipedtele config``."""
    res = _config_cmd("--set", 'network.password="hunter2"', "--set", 'network.user="leader"')
    assert res.returncode == 0, res.stderr
    assert "hunter2" not in res.stdout and "hunter2" not in res.stderr
    data = json.loads(res.stdout)
    assert data["network"]["password"] == "***" and data["network"]["user"] == "leader"


def test_intercontinental_profile_carries_the_task_course_and_the_security_settings() -> None:
    """Issue 15 item 9: the intercontinental profile had no [world] course for the pilot."""
    cfg = load_config("intercontinental")
    assert cfg.section("world").obstacles == load_config("localhost-delay").section("world").obstacles
    assert len(cfg.section("world").obstacles) == 5
    assert cfg.section("leader").operator == "pilot"
    net = cfg.section("network")
    assert net.message_key_file == "secrets/message.key"
    assert net.publishers_allowed == ["leader"] and net.followers_allowed == ["follower"]
    assert net.tls_mutual and net.password_file and not net.password
    assert cfg.section("clock").mode == "ntp"
