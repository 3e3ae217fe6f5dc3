"""Restart the router under a running teleoperation: both sides reconnect by themselves.

The router is killed (SIGKILL) while the scripted leader makes the robot walk, stays down
longer than the follower's watchdog period, then a new router process starts on the same
port. The follower must stop safely during the outage, and the same leader and follower
processes must reconnect (Zenoh client reconnection) and resume: walking again, commands
of the same leader session accepted, feedback reaching the leader. No process crashes.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from e2e_support import (
    NO_BLIND_STOP,
    NO_VIDEO,
    Monitor,
    Procs,
    free_port,
    records,
    start_follower,
    start_leader,
    start_router,
    walking_script,
)

OUTAGE_S = 3.0  # > the watchdog period (0.5 s) and long enough for Zenoh to back off


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(150)
def test_router_restart_both_sides_reconnect(procs: Procs, tmp_path: Path) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    f_rec, l_rec = tmp_path / "follower.mcap", tmp_path / "leader.mcap"
    router = start_router(procs, ep)
    follower = start_follower(procs, ep, NO_VIDEO, record=f_rec)
    # the outage stops the robot by the leader's blind stop too, which waits for a handle move
    leader = start_leader(procs, ep, [*walking_script(5.0), *NO_BLIND_STOP], record=l_rec)
    with Monitor(ep) as mon:
        mon.wait_state("walking", time.time() - 60, timeout_s=30.0, hold_s=2.0)
        t_kill = time.time()
        router.signal(signal.SIGKILL)
        router.popen.wait(timeout=10)
        time.sleep(OUTAGE_S)
        t_back = time.time()
        start_router(procs, ep, name="router2")
        # the monitor is a client of the same router: it reconnects too
        t_walk_again = mon.wait_state("walking", t_back, timeout_s=30.0, hold_s=2.0)
    assert leader.alive(), leader.tail()
    assert follower.alive(), follower.tail()
    assert leader.stop() == 0, leader.tail()
    assert follower.stop() == 0, follower.tail()
    for p in (leader, follower):
        assert "Traceback" not in p.log(), p.tail()

    # ---- the follower: safe stop during the outage, same leader session after it
    fbs = [r.data for r in records(f_rec, "feedback/sent")]
    events = [r.data for r in records(f_rec, "events")]
    cmds = records(f_rec, "cmd/recv")
    stops = [e for e in events if e["event"] == "watchdog_stop" and t_kill < e["t"] < t_back + 0.5]
    assert len(stops) == 1 and stops[0]["why"] == "no fresh command", events
    outage = [d["state"] for d in fbs if stops[0]["t"] < d["t"] < t_back]
    assert outage and "walking" not in outage, outage
    assert "standing" in outage, "the robot did not come to a stand while the router was down"
    assert not any(d["state"] == "fallen" for d in fbs)
    assert not any(e["event"] in ("fall", "collision") for e in events)
    sids = {r.data["sid"] for r in cmds}
    assert len(sids) == 1, f"one leader session all along, got {sids}"
    assert any(r.t_recv > t_back for r in cmds), "no command reached the follower after the restart"
    assert sum(1 for d in fbs if d["t"] > t_back and d["state"] == "walking") > 50
    assert len({d["sid"] for d in fbs}) == 1

    # ---- the leader: feedback stopped during the outage and resumed after it
    fb_recv = [r.t_recv for r in records(l_rec, "feedback/recv")]
    assert not any(t_kill + 0.2 < t < t_back for t in fb_recv)
    assert sum(1 for t in fb_recv if t > t_back) > 50
    # ... its force feedback faded out while the link was down and came back after
    states = [r.data for r in records(l_rec, "leader/state")]
    during = [s for s in states if t_kill + 1.0 < s["t"] < t_back]
    assert during and all(s["link"] != "ok" for s in during), {s["link"] for s in during}
    assert during[-1]["gain"] == 0.0
    assert states[-1]["t"] > t_back and states[-1]["link"] == "ok" and states[-1]["gain"] == 1.0
    reconnect_s = min(t for t in fb_recv if t > t_back) - t_back
    print(
        f"feedback back at the leader {reconnect_s:.2f} s after the new router started; "
        f"robot walking again after {t_walk_again - t_back:.2f} s"
    )
