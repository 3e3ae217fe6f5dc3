"""Garbage on every key during a run: counted, logged, no effect on the robot.

While the scripted leader makes the robot walk through a router, a third process
(``garbage.py``) publishes 200 invalid payloads on each of the robot's five keys. Every one
that reaches a receiver must be dropped and counted (the follower subscribes to ``cmd``,
``clock`` and ``status``; the leader to ``feedback``, ``video``, ``status`` and ``clock``; both publish their drop
counters as ``drop_<reason>`` in their Status), the drops must be logged, and the robot
must keep walking as if nothing happened.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
from bipedtele.link.messages import Status
from e2e_support import (
    HERE,
    Monitor,
    Procs,
    free_port,
    records,
    start_follower,
    start_leader,
    start_router,
    wait_until,
    walking_script,
)

COUNT = 200


def _drops(st: Status) -> int:
    return sum(v for k, v in st.counters.items() if k.startswith("drop_"))


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(150)
def test_garbage_on_every_key_is_dropped_and_counted(procs: Procs, tmp_path: Path) -> None:
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    f_rec = tmp_path / "follower.mcap"
    start_router(procs, ep)
    # video on, slowly: the leader's video receiver is under attack too
    follower = start_follower(
        procs, ep, ["--set", "follower.camera_fps=2", "--set", 'follower.cameras=["scene"]'], record=f_rec
    )
    leader = start_leader(procs, ep, walking_script(5.0))
    with Monitor(ep) as mon:

        def latest(role: str) -> Status | None:
            mon.poll()
            sts = [r.msg for r in mon.status if r.msg.role == role]
            return sts[-1] if sts else None

        mon.wait_state("walking", time.time() - 60, timeout_s=30.0, hold_s=1.5)
        wait_until(lambda: latest("leader") is not None and latest("follower") is not None, 10.0, "status of both")
        f0, l0 = latest("follower"), latest("leader")
        assert f0 is not None and l0 is not None
        t0 = time.time()
        g = procs.start(
            "garbage", [str(HERE / "garbage.py"), "--connect", ep, "--count", str(COUNT), "--seconds", "2"], raw=True
        )
        assert g.popen.wait(timeout=60) == 0, g.tail()
        t1 = time.time()
        report = json.loads(g.log().strip().splitlines()[-1])
        sent = report["sent"]
        assert sent == {k: COUNT for k in ("cmd", "feedback", "video", "clock", "status")}
        want_f = sent["cmd"] + sent["clock"] + sent["status"]  # the follower reads the leader's status (uplink budget)
        want_l = sent["feedback"] + sent["video"] + sent["status"] + sent["clock"]

        def counted() -> bool:
            f, ll = latest("follower"), latest("leader")
            return (
                f is not None
                and ll is not None
                and _drops(f) - _drops(f0) >= want_f
                and _drops(ll) - _drops(l0) >= want_l
            )

        wait_until(
            counted,
            10.0,
            "the drops counted in both statuses",
            lambda: f"follower {latest('follower')}\nleader {latest('leader')}",
        )
        mon.wait_state("walking", t1, timeout_s=5.0, hold_s=1.0)
        f1, l1 = latest("follower"), latest("leader")
        assert f1 is not None and l1 is not None
        states = mon.states_since(t0)
    assert leader.stop() == 0, leader.tail()
    assert follower.stop() == 0, follower.tail()

    # every payload was dropped and counted, exactly once, by the side that subscribes
    assert _drops(f1) - _drops(f0) == want_f, f1.counters
    assert _drops(l1) - _drops(l0) == want_l, l1.counters
    reasons = {k for k, v in {**f1.counters, **l1.counters}.items() if k.startswith("drop_") and v}
    assert {
        "drop_not_msgpack",
        "drop_not_a_map",
        "drop_bad_version",
        "drop_unknown_kind",
        "drop_bad_field",
        "drop_missing_field",
    } <= reasons, reasons
    # ... and logged (rate-limited: one line per reason per interval)
    assert "follower: dropped" in follower.log() and "not_msgpack" in follower.log()
    assert "leader: dropped" in leader.log() and "not_msgpack" in leader.log()
    for p in (leader, follower):
        assert "Traceback" not in p.log(), p.tail()

    # no effect on the robot: walking all along, commands still accepted, no fall
    assert states and set(states) == {"walking"}, set(states)
    assert f1.counters["cmd_accepted"] > f0.counters["cmd_accepted"] + 50
    assert f1.counters["falls"] == 0 and f1.counters["watchdog_stops"] == f0.counters["watchdog_stops"]
    fbs = [r.data for r in records(f_rec, "feedback/sent") if t0 <= r.data["t"] <= t1 + 1.0]
    assert fbs and {d["state"] for d in fbs} == {"walking"}
    assert fbs[-1]["pose"][0] > fbs[0]["pose"][0], "the robot stopped moving forward"
    assert not any(
        r.data["event"] in ("fall", "watchdog_stop") and t0 <= r.data["t"] <= t1 + 1.0 for r in records(f_rec, "events")
    )
