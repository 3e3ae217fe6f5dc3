"""A leader whose commands the router refuses is told so, and its run fails.

A real router on loopback (plain tcp) with user/password authentication and roles:
``leader`` may publish commands, ``follower`` may publish feedback and video. A sim
follower logs in as ``follower``. Then:

1. a leader started with the *follower's* login (a copy-paste slip in a two-host setup):
   its session opens, but the router's access control drops every command it sends, so the
   robot never moves. The leader must say within about 2 s, in one WARNING line, that its
   commands do not reach the robot, and exit non-zero with a summary that says so (before:
   it sent its commands into the void and exited 0 with a normal summary);
2. the same leader with the leader's login: no such warning, exit 0, and the follower
   applied its commands.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
from e2e_support import NO_VIDEO, Procs, free_port, records, start_follower, walking_script

WARNING = "commands not reaching the robot: refused by the router's ACL?"
LEADER_S = 6.0


def _profiles(d: Path) -> dict[str, Path]:
    """Router and client profiles (password files 0600)."""
    creds = d / "creds.txt"
    creds.write_text("leader:leader-pw\nfollower:follower-pw\n")
    for user in ("leader", "follower"):
        (d / f"{user}.pw").write_text(f"{user}-pw\n")
    for f in (creds, d / "leader.pw", d / "follower.pw"):
        f.chmod(0o600)
    out = {
        "router": f'[network]\ncredentials_file = "{creds}"\npublishers_allowed = ["leader"]\n'
        'followers_allowed = ["follower"]\n',
        "as_leader": f'[network]\nuser = "leader"\npassword_file = "{d}/leader.pw"\n',
        "as_follower": f'[network]\nuser = "follower"\npassword_file = "{d}/follower.pw"\n',
    }
    paths = {}
    for name, text in out.items():
        paths[name] = d / f"{name}.toml"
        paths[name].write_text(text)
    return paths


def _leader(procs: Procs, endpoint: str, profile: Path, name: str) -> tuple[int, str, float | None]:
    """Run a scripted leader for LEADER_S; return (exit code, log, seconds from ready to the
    warning, or None)."""
    args = [
        "leader",
        "--config",
        str(profile),
        "--set",
        'network.mode="client"',
        "--set",
        f'network.connect=["{endpoint}"]',
        "--set",
        "network.listen=[]",
        *walking_script(5.0),
        "--duration",
        f"{LEADER_S:g}",
        "--set",
        "record.enabled=false",
    ]
    p = procs.start(name, args)
    t_ready = t_warn = None
    deadline = time.monotonic() + 90.0
    while p.alive() and time.monotonic() < deadline:
        log = p.log()
        if t_ready is None and "leader ready" in log:
            t_ready = time.monotonic()
        if t_warn is None and WARNING in log:
            t_warn = time.monotonic()
        time.sleep(0.05)
    rc = p.popen.wait(timeout=30)
    log = p.log()
    if t_warn is None and WARNING in log:
        t_warn = time.monotonic()
    delay = None if t_ready is None or t_warn is None else t_warn - t_ready
    return rc, log, delay


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_leader_refused_by_the_acl_is_told_and_fails(procs: Procs, tmp_path: Path) -> None:
    prof = _profiles(tmp_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = procs.start("router", ["router", "--config", str(prof["router"]), "--listen", endpoint])
    router.wait_log(r"router: \S+ listening on", 30.0)
    f_rec = tmp_path / "follower.mcap"
    start_follower(procs, endpoint, ["--config", str(prof["as_follower"]), *NO_VIDEO], record=f_rec)

    # 1. The follower's login: the router drops its commands.
    t_rogue = time.time()
    rc, log, delay = _leader(procs, endpoint, prof["as_follower"], "leader-as-follower")
    t_rogue_end = time.time()
    print(f"refused leader: exit {rc}, warning {delay if delay is None else round(delay, 2)} s after 'leader ready'")
    assert rc != 0, log
    assert log.count(WARNING) == 1, log
    summary = [ln for ln in log.splitlines() if ln.startswith("leader: operator")]
    assert len(summary) == 1 and "NO COMMAND REACHED THE ROBOT" in summary[0], log
    assert delay is not None

    # 2. The leader's login: its commands reach the robot; nothing to warn about.
    t_proper = time.time()
    rc, log, _ = _leader(procs, endpoint, prof["as_leader"], "leader")
    assert rc == 0, log
    assert WARNING not in log and "NO COMMAND" not in log, log
    assert re.search(r"leader: operator scripted, stopped, \d", log), log

    # The verdicts were true: the follower received commands only from the proper leader.
    cmds = records(f_rec, "cmd/recv") if f_rec.exists() else []
    if not cmds:  # the follower writes its recording as it goes; read it once stopped
        procs.close()
        cmds = records(f_rec, "cmd/recv")
    assert not [r for r in cmds if t_rogue <= r.t_recv <= t_rogue_end]
    assert len([r for r in cmds if r.t_recv >= t_proper]) > 100
