"""netem: tc command construction, dry run, detection of a kernel without sch_netem, and
the trace replay of `bipedtele demo --delay-backend netem` (its plan, with --dry-run)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from bipedtele.config.profile import ConfigError
from bipedtele.tools.netem import netem_available, tc_commands

pytestmark = pytest.mark.timeout(60)


def _netem(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "netem", *args], capture_output=True, text=True, timeout=30
    )


def test_tc_commands() -> None:
    assert tc_commands("apply", "veth0", "150ms", "20ms", "normal", "0.1%") == [
        [
            "tc",
            "qdisc",
            "replace",
            "dev",
            "veth0",
            "root",
            "netem",
            "delay",
            "150ms",
            "20ms",
            "distribution",
            "normal",
            "loss",
            "0.1%",
        ]
    ]
    assert tc_commands("apply", "eth0", "0.2s") == [
        ["tc", "qdisc", "replace", "dev", "eth0", "root", "netem", "delay", "0.2s"]
    ]
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
    res = _netem(
        "apply",
        "--dev",
        "lo",
        "--delay",
        "150ms",
        "--jitter",
        "20ms",
        "--distribution",
        "normal",
        "--loss",
        "0.1%",
        "--dry-run",
    )
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


# --------------------------------------------------------------- trace replay (demo netem)


def _demo(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "demo", *args], capture_output=True, text=True, timeout=60, cwd=cwd
    )


def test_netem_args_realise_each_model() -> None:
    from bipedtele.link.delaymodels import parse_delay_model
    from bipedtele.tools.netem_trace import netem_args

    assert netem_args(parse_delay_model("const:150ms")) == ["delay", "150000us", "limit", "10000"]
    assert netem_args(parse_delay_model("uniform:150ms:30ms")) == ["delay", "150000us", "30000us", "limit", "10000"]
    assert netem_args(parse_delay_model("normal:150ms:20ms")) == [
        "delay",
        "150000us",
        "20000us",
        "distribution",
        "normal",
        "limit",
        "10000",
    ]
    trace = parse_delay_model("trace:intercontinental:h1")
    assert netem_args(trace, 0.0)[:2] == ["delay", "133160us"]  # first row of the shipped trace
    assert netem_args(trace, 0.05)[:2] == ["delay", "132870us"]
    assert netem_args(trace, 300.05)[:2] == ["delay", "132870us"]  # looped: period 300 s


def test_replay_times_are_the_trace_rows_looped() -> None:
    from bipedtele.link.delaymodels import TraceDelay, parse_delay_model
    from bipedtele.tools.netem_trace import replay_times

    trace = TraceDelay([0.0, 0.1, 0.2], [0.1, 0.11, 0.12])  # period 0.3 s
    assert list(replay_times(trace, 0.65)) == pytest.approx([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    shifted = TraceDelay([5.0, 5.5], [0.1, 0.2])  # rows at 5.0 and 5.5 s, period 1 s
    assert list(replay_times(shifted, 2.0)) == pytest.approx([0.5, 1.0, 1.5, 2.0])
    assert list(replay_times(parse_delay_model("const:100ms"), 10.0)) == []
    shipped = parse_delay_model("trace:intercontinental:h2")
    assert len(list(replay_times(shipped, 60.0))) == 1200  # 20 Hz, its own sample rate


def test_demo_dry_run_prints_the_netem_plan_over_time(tmp_path: Path) -> None:
    trace = tmp_path / "trace.csv"
    trace.write_text("t_s,h1_ms,h2_ms\n0.0,100,200\n0.1,110,190\n0.2,120.5,180\n")
    res = _demo(
        "--delay-backend",
        "netem",
        "--dry-run",
        "--delay-trace",
        str(trace),
        "--duration",
        "0.45",
        "--headless",
        "--run-dir",
        str(tmp_path / "run"),
    )
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    head = next(line for line in lines if line.startswith("# netem backend:"))
    m = re.search(
        r"leader in (bt-dl-\w+) \((btdl-\w+) 10\.233\.0\.1\), follower and router in (bt-df-\w+) \((btdf-\w+) 10\.233\.0\.2\)",
        head,
    )
    assert m, head
    l_ns, l_dev, f_ns, f_dev = m.groups()
    # processes: router and follower in the follower's namespace, the leader in its own,
    # the leader dialling the router across the veth pair; no proxy
    procs = {line.split(":")[0][len("# process ") :]: line for line in lines if line.startswith("# process ")}
    assert set(procs) == {"router", "follower", "leader"}
    assert f"ip netns exec {f_ns} " in procs["router"] and "--listen tcp/10.233.0.2:" in procs["router"]
    assert f"ip netns exec {f_ns} " in procs["follower"]
    assert f"ip netns exec {l_ns} " in procs["leader"] and 'network.connect=["tcp/10.233.0.2:' in procs["leader"]
    setup = lines[lines.index("# setup") + 1 : lines.index("# setup") + 12]
    assert setup == [
        f"ip netns add {l_ns}",
        f"ip netns add {f_ns}",
        f"ip link add {l_dev} type veth peer name {f_dev}",
        f"ip link set {l_dev} netns {l_ns}",
        f"ip link set {f_dev} netns {f_ns}",
        f"ip -n {l_ns} addr add 10.233.0.1/30 dev {l_dev}",
        f"ip -n {f_ns} addr add 10.233.0.2/30 dev {f_dev}",
        f"ip -n {l_ns} link set lo up",
        f"ip -n {f_ns} link set lo up",
        f"ip -n {l_ns} link set {l_dev} up",
        f"ip -n {f_ns} link set {f_dev} up",
    ]
    tc = [line for line in lines if re.match(r"^\d+\.\d{3} tc ", line)]
    L = f"tc -n {l_ns} qdisc {{}} dev {l_dev} root netem delay {{}} limit 10000"
    F = f"tc -n {f_ns} qdisc {{}} dev {f_dev} root netem delay {{}} limit 10000"
    assert tc == [
        "0.000 " + L.format("add", "100000us"),
        "0.000 " + F.format("add", "200000us"),
        "0.100 " + L.format("change", "110000us"),
        "0.100 " + F.format("change", "190000us"),
        "0.200 " + L.format("change", "120500us"),
        "0.200 " + F.format("change", "180000us"),
        "0.300 " + L.format("change", "100000us"),
        "0.300 " + F.format("change", "200000us"),  # looped
        "0.400 " + L.format("change", "110000us"),
        "0.400 " + F.format("change", "190000us"),
    ]
    assert lines[-2:] == [f"ip netns del {l_ns}", f"ip netns del {f_ns}"]
    assert not (tmp_path / "run").exists()  # a dry run starts nothing


def test_demo_auto_backend_says_which(tmp_path: Path) -> None:
    res = _demo(
        "--delay-backend", "auto", "--dry-run", "--headless", "--duration", "1", "--run-dir", str(tmp_path / "r")
    )
    assert res.returncode == 0, res.stderr
    first = res.stdout.splitlines()[0]
    ok, why = netem_available()
    if ok and os.geteuid() == 0:
        assert first == f"delay backend: netem ({why})"
    else:
        assert first.startswith("delay backend: proxy (") and ("netem unavailable" in first or "root" in first)
        assert any(line.startswith("# process proxy: ") for line in res.stdout.splitlines())


def test_demo_netem_backend_refused_in_one_line_where_it_cannot_run(tmp_path: Path) -> None:
    ok, why = netem_available()
    if ok and os.geteuid() == 0:
        pytest.skip(f"netem can run here ({why})")
    res = _demo("--delay-backend", "netem", "--headless", "--duration", "1", "--run-dir", str(tmp_path / "r"))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "--delay-backend netem:" in lines[0] and "allowed here: proxy, or auto" in lines[0]
    assert not (tmp_path / "r").exists()


def test_loss_bursts_rate_and_queue_become_netem_options() -> None:
    """The packet emulator's specs realised by netem (issue 19: the netem backend does the same)."""
    from bipedtele.link.delaymodels import parse_delay_model
    from bipedtele.tools.netem_trace import impairment_args, netem_args

    assert impairment_args(loss="1%") == ["loss", "random", "1%"]
    assert impairment_args(loss="ge:p=1%,r=30%,bad=80%,good=0.1%") == ["loss", "gemodel", "1%", "30%", "80%", "0.1%"]
    assert impairment_args(rate="600kbit", queue="64kB") == ["rate", "600000bit", "limit", "42"]
    assert impairment_args() == []
    extra = impairment_args(loss="1%", rate="300kbit", queue="64kB")
    assert netem_args(parse_delay_model("const:150ms"), 0.0, extra) == [
        "delay",
        "150000us",
        "loss",
        "random",
        "1%",
        "rate",
        "300000bit",
        "limit",
        "42",
    ]
    assert netem_args(parse_delay_model("const:150ms"), 0.0, ["loss", "random", "1%"])[-2:] == ["limit", "10000"]
    with pytest.raises(ConfigError, match="ge:p=P,r=R"):
        impairment_args(loss="ge:q=1%")
    assert tc_commands("apply", "eth0", "150ms", loss="ge:p=1%,r=30%", rate="600kbit", queue="32kB") == [
        [
            "tc",
            "qdisc",
            "replace",
            "dev",
            "eth0",
            "root",
            "netem",
            "delay",
            "150ms",
            "loss",
            "gemodel",
            "1%",
            "30%",
            "100%",
            "0%",
            "rate",
            "600000bit",
            "limit",
            "21",
        ],
    ]


def test_dry_run_prints_loss_bursts_and_rate() -> None:
    res = _netem(
        "apply",
        "--dev",
        "lo",
        "--delay",
        "150ms",
        "--loss",
        "ge:p=1%,r=30%",
        "--rate",
        "600kbit",
        "--queue",
        "64kB",
        "--dry-run",
    )
    assert res.returncode == 0, res.stderr
    assert (
        res.stdout.strip()
        == "tc qdisc replace dev lo root netem delay 150ms loss gemodel 1% 30% 100% 0% rate 600000bit limit 42"
    )
    res = _netem("apply", "--dev", "lo", "--delay", "150ms", "--rate", "fast", "--dry-run")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1, res.stderr


def test_replay_schedule_keeps_the_impairments_on_every_change() -> None:
    from bipedtele.link.delaymodels import TraceDelay, parse_delay_model
    from bipedtele.tools.netem_trace import impairment_args, schedule
    from bipedtele.tools.netns import FOLLOWER, LEADER, VethLink

    link = VethLink(tag="abcd")
    up = impairment_args(rate="300kbit", queue="64kB")
    steps = list(
        schedule(
            link,
            parse_delay_model("const:10ms"),
            TraceDelay([0.0, 0.1], [0.1, 0.2]),
            0.25,
            extra={FOLLOWER: up, LEADER: impairment_args(loss="1%")},
        )
    )
    assert [s.t for s in steps] == pytest.approx([0.0, 0.0, 0.1, 0.2])
    for s in steps:
        tail = " ".join(s.command).split(" netem ", 1)[1]
        if s.side == FOLLOWER:
            assert tail.endswith("rate 300000bit limit 42"), tail
        else:
            assert tail.endswith("loss random 1% limit 10000"), tail


def test_demo_netem_backend_carries_loss_and_rate_caps(tmp_path: Path) -> None:
    """`demo --delay-backend netem --loss --rate-up --rate-down` (dry run): every qdisc carries them."""
    trace = tmp_path / "trace.csv"
    trace.write_text("t_s,h1_ms,h2_ms\n0.0,100,200\n0.1,110,190\n")
    res = _demo(
        "--delay-backend",
        "netem",
        "--dry-run",
        "--delay-trace",
        str(trace),
        "--duration",
        "0.25",
        "--headless",
        "--loss",
        "1%",
        "--rate-up",
        "2mbit",
        "--rate-down",
        "300kbit",
        "--run-dir",
        str(tmp_path / "run"),
    )
    assert res.returncode == 0, res.stderr
    tc = [line for line in res.stdout.splitlines() if re.match(r"^\d+\.\d{3} tc ", line)]
    assert tc and all("loss random 1%" in line for line in tc), tc
    assert all(line.endswith("rate 2000000bit limit 42") for line in tc if "btdl-" in line), tc
    assert all(line.endswith("rate 300000bit limit 42") for line in tc if "btdf-" in line), tc
    procs = [line for line in res.stdout.splitlines() if line.startswith("# process ")]
    assert procs and all('network.links="split"' in line for line in procs), procs
    res = _demo(
        "--delay-backend",
        "netem",
        "--dry-run",
        "--headless",
        "--outage",
        "at=5s,for=3s",
        "--run-dir",
        str(tmp_path / "r2"),
    )
    assert res.returncode == 2 and "--outage" in res.stderr and len(res.stderr.strip().splitlines()) == 1, res.stderr
