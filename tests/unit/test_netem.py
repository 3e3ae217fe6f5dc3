"""netem: tc command construction, dry run, and detection of a kernel without sch_netem."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from bipedtele.config import ConfigError
from bipedtele.netem import netem_available, tc_commands

pytestmark = pytest.mark.timeout(60)


def _netem(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "netem", *args], capture_output=True, text=True, timeout=30
    )


def test_tc_commands() -> None:
    assert tc_commands("apply", "veth0", "150ms", "20ms", "normal", "0.1%") == [
        ["tc", "qdisc", "replace", "dev", "veth0", "root", "netem", "delay", "150ms", "20ms", "distribution", "normal", "loss", "0.1%"]
    ]
    assert tc_commands("apply", "eth0", "0.2s") == [["tc", "qdisc", "replace", "dev", "eth0", "root", "netem", "delay", "0.2s"]]
    assert tc_commands("clear", "eth0") == [["tc", "qdisc", "del", "dev", "eth0", "root"]]
    assert tc_commands("show", "eth0") == [["tc", "qdisc", "show", "dev", "eth0"]]


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"delay": None}, "--delay"),
        ({"delay": "150"}, "--delay '150'"),
        ({"delay": "150ms", "jitter": "x"}, "--jitter"),
        ({"delay": "150ms", "distribution": "normal"}, "only with --jitter"),
        ({"delay": "150ms", "jitter": "5ms", "distribution": "gauss"}, "allowed: uniform, normal"),
        ({"delay": "150ms", "loss": "5"}, "percentage"),
    ],
)
def test_bad_arguments(kw: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        tc_commands("apply", "eth0", **kw)
    with pytest.raises(ConfigError, match="interface"):
        tc_commands("show", "eth0; rm -rf /")


def test_dry_run_prints_commands() -> None:
    res = _netem("apply", "--dev", "lo", "--delay", "150ms", "--jitter", "20ms", "--distribution", "normal", "--loss", "0.1%", "--dry-run")
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "tc qdisc replace dev lo root netem delay 150ms 20ms distribution normal loss 0.1%"
    res = _netem("clear", "--dev", "lo", "--dry-run")
    assert res.stdout.strip() == "tc qdisc del dev lo root"
    res = _netem("apply", "--dev", "lo", "--delay", "abc", "--dry-run")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1


def test_detection_from_kernel_files(tmp_path: Path) -> None:
    if shutil.which("tc") is None:
        ok, why = netem_available()
        assert not ok and "`tc`" in why
        pytest.skip("tc is not installed: only the missing-tc path can be checked")
    mods = tmp_path / "modules"
    mods.write_text("sch_netem 40960 0 - Live 0x0000000000000000\n")
    none = tmp_path / "none"
    assert netem_available(proc_modules=mods, sys_module=none, modules_dir=tmp_path) == (True, "sch_netem is loaded")
    (tmp_path / "modules.builtin").write_text("kernel/net/sched/sch_netem.ko\n")
    mods.write_text("other_mod 1 0 - Live 0x0\n")
    ok, why = netem_available(proc_modules=mods, sys_module=none, modules_dir=tmp_path)
    assert ok and "built into" in why


def test_without_netem_exits_1_pointing_to_proxy() -> None:
    ok, why = netem_available()
    res = _netem("apply", "--dev", "lo", "--delay", "150ms")
    if ok:
        pytest.skip(f"this kernel has netem ({why}); the missing-netem path cannot be shown here")
    assert res.returncode == 1
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "netem unavailable" in lines[0] and "bipedtele delay-proxy" in lines[0]
