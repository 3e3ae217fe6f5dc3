"""Kill the leader mid-walk: the follower stands by itself; a new leader takes over.

Router, follower and a scripted leader (walking at 5 cm/s) run as separate processes, both
sides Zenoh clients of the router. The leader is killed with SIGKILL (no goodbye, no
``enable = false``): the follower's watchdog must stop the robot within its period
(0.5 s from the last command received) plus one walking cycle, without a fall. A second
leader process then drives the same follower process again.
"""

from __future__ import annotations

import signal
import time
from pathlib import Path

import pytest
from e2e_support import (
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

WATCHDOG_S = 0.5  # the [follower] default, set explicitly below
CONTROL_HZ = 50.0
# Scheduling allowance on a loaded 2-core machine: the follower's loop may run a few
# periods late while four processes and pybullet share the CPUs.
SLACK_S = 0.15


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(150)
def test_kill_leader_mid_walk_then_new_leader(procs: Procs, tmp_path: Path) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    follower_rec = tmp_path / "follower.mcap"
    start_router(procs, ep)
    follower = start_follower(
        procs,
        ep,
        [*NO_VIDEO, "--set", f"follower.watchdog_s={WATCHDOG_S}", "--set", f"follower.control_rate_hz={CONTROL_HZ:g}"],
        record=follower_rec,
    )
    with Monitor(ep) as mon:
        leader1 = start_leader(procs, ep, walking_script(5.0), name="leader1")
        t_walk = mon.wait_state("walking", time.time() - 60, timeout_s=30.0, hold_s=3.0)
        assert t_walk > 0
        t_kill = time.time()
        leader1.signal(signal.SIGKILL)
        leader1.popen.wait(timeout=10)
        mon.wait_state("standing", t_kill, timeout_s=10.0, hold_s=1.0)
        assert follower.alive(), follower.tail()

        t_restart = time.time()
        leader2 = start_leader(procs, ep, walking_script(5.0), name="leader2")
        mon.wait_state("walking", t_restart, timeout_s=30.0, hold_s=2.0)
        assert leader2.stop() == 0, leader2.tail()
        assert follower.alive(), follower.tail()
        assert not any(s == "fallen" for s in mon.states_since(0.0))
    assert follower.stop() == 0, follower.tail()

    # ---- what the follower recorded
    cmds = records(follower_rec, "cmd/recv")
    fbs = records(follower_rec, "feedback/sent")
    events = [r.data for r in records(follower_rec, "events")]
    sids = list(dict.fromkeys(r.data["sid"] for r in cmds))
    assert len(sids) == 2, f"expected commands from two leader sessions, got sids {sids}"
    old, new = sids
    t_last_old = max(r.t_recv for r in cmds if r.data["sid"] == old)
    assert t_last_old <= t_kill + 0.05, "the killed leader's commands kept arriving"

    # walking cycle T [s] the robot used when the leader died
    walking_before = [r.data for r in fbs if r.data["state"] == "walking" and r.t_recv <= t_last_old]
    assert len(walking_before) > 100, "the robot did not walk before the kill"
    cycle_s = walking_before[-1]["T"]
    assert 0.1 < cycle_s < 5.0

    stops = [e for e in events if e["event"] == "watchdog_stop" and t_last_old < e["t"] < t_restart]
    assert len(stops) == 1, events
    assert stops[0]["why"] == "no fresh command"
    t_stop = stops[0]["t"]
    # the watchdog fires after its period without a command, not before
    assert WATCHDOG_S <= t_stop - t_last_old <= WATCHDOG_S + 1.0 / CONTROL_HZ + SLACK_S

    after = [r.data for r in fbs if t_last_old < r.data["t"] < t_restart]
    t_stand = next(d["t"] for d in after if d["state"] == "standing")
    assert t_stand - t_last_old <= WATCHDOG_S + cycle_s + SLACK_S, (t_stand - t_last_old, cycle_s)
    # it stayed standing until the new leader came
    states_after_stand = {d["state"] for d in after if d["t"] >= t_stand}
    assert states_after_stand == {"standing"}, states_after_stand

    # ---- no fall, no collision, anywhere in the run
    assert not any(r.data["state"] == "fallen" for r in fbs)
    assert not any(e["event"] in ("fall", "collision") for e in events)
    statuses = [r.data for r in records(follower_rec, "status/sent")]
    assert statuses[-1]["counters"]["falls"] == 0

    # ---- the new leader drove the same follower process
    t_first_new = min(r.t_recv for r in cmds if r.data["sid"] == new)
    assert t_first_new > t_restart
    walking_new = [r.data for r in fbs if r.data["t"] > t_first_new and r.data["state"] == "walking"]
    assert len(walking_new) > 50
    assert {d["cmd_seq"] for d in walking_new} - {0}, "feedback did not echo the new commands"
    accepted = [(r.t_recv, r.data["counters"]["cmd_accepted"]) for r in records(follower_rec, "status/sent")]
    at_restart = max(n for t, n in accepted if t <= t_restart)
    assert accepted[-1][1] > at_restart + 50
    assert len({r.data["sid"] for r in fbs}) == 1, "the follower restarted"
