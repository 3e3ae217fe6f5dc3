"""A replayed earlier session's video is never shown as live (issue 32, item 4), against real
processes: a Zenoh router, the follower on the pybullet NAO (twice: an earlier and a new
session), a leader, and a capturing attacker, each its own process on loopback.
"""

from __future__ import annotations

import json
import textwrap
import time
from pathlib import Path

import pytest
from adversary_support import make_key_file, wait_recorded_state
from e2e_support import Procs, free_port, records, start_follower, start_leader, start_router, walking_script

# Captures the signed video frames for CAPTURE_S, waits for the TRIGGER file, then
# republishes them verbatim at 10 Hz for REPLAY_S (no key needed: they are signed).
CAPTURE_TRIGGER_REPLAY = textwrap.dedent(
    """
    import json, os, sys, time, zenoh
    ep, key, trigger, capture_s, replay_s = sys.argv[1], sys.argv[2], sys.argv[3], *map(float, sys.argv[4:6])
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([ep]))
    c.insert_json5("scouting/multicast/enabled", "false")
    got = []
    with zenoh.open(c) as s:
        sub = s.declare_subscriber(key, lambda sample: got.append(sample.payload.to_bytes()))
        time.sleep(capture_s)
        sub.undeclare()
        print(json.dumps({"captured": len(got), "t_captured": time.time()}), flush=True)
        while not os.path.exists(trigger):
            time.sleep(0.02)
        pub = s.declare_publisher(key)
        t0, n = time.time(), 0
        print(json.dumps({"replay_from": t0}), flush=True)
        while time.time() - t0 < replay_s and got:
            pub.put(got[n % len(got)])
            n += 1
            time.sleep(0.1)
        print(json.dumps({"replayed": n}), flush=True)
    """
)
VIDEO = ["--set", "follower.camera_fps=5", "--set", 'follower.cameras=["head"]', "--set", 'clock.mode="synced"']


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_replayed_earlier_sessions_video_is_never_shown(procs: Procs, tmp_path: Path) -> None:
    """An attacker replays 2 s of an earlier follower session's signed video at 10 Hz.

    Setup: message key on both ends, synced clocks. Follower 1 runs; the attacker captures
    its video frames; follower 1 stops. The replay starts, a new leader starts (seeing only
    the replay for 2 s), then follower 2 starts and the leader walks it.

    Before (the issue's finding: 49-59 s old frames shown as the live feed): the replay bound
    the leader's video gate (video under the watch key, which never changes, no age bound),
    so the old frames were the live feed and follower 2's were dropped as
    ``foreign_session``. Now no frame of follower 1's session is shown (recorded as
    ``video/recv``, handed to the cockpit), follower 2's are.
    """
    ep = f"tcp/127.0.0.1:{free_port()}"
    key = make_key_file(tmp_path / "message.key")
    keyed = ["--set", f'network.message_key_file="{key}"', *VIDEO]
    start_router(procs, ep)
    f1_rec, f2_rec, l_rec = tmp_path / "follower1.mcap", tmp_path / "follower2.mcap", tmp_path / "leader.mcap"
    follower1 = start_follower(procs, ep, keyed, record=f1_rec, name="follower1")
    script, trigger = tmp_path / "capture_replay.py", tmp_path / "replay.now"
    script.write_text(CAPTURE_TRIGGER_REPLAY)
    attacker = procs.start("attacker", [str(script), ep, "bipedtele/nao1/video", str(trigger), "2.0", "25.0"], raw=True)
    attacker.wait_log(r'"captured"', 20.0)
    assert follower1.stop() == 0, follower1.tail()
    t_stop1 = time.time()
    trigger.write_text("now")
    attacker.wait_log(r'"replay_from"', 10.0)
    leader = start_leader(procs, ep, [*keyed, *walking_script(5.0)], record=l_rec)
    time.sleep(2.0)  # the leader hears only the replay
    t_start2 = time.time()
    start_follower(procs, ep, keyed, record=f2_rec, name="follower2")
    t_walk = wait_recorded_state(f2_rec, "walking", time.time(), timeout_s=30.0, hold_s=1.0)
    time.sleep(2.0)
    assert attacker.alive(), "the replay ended before the end"
    assert leader.stop() in (0, 3), leader.tail()
    # a frame's capture time tells the sessions apart: before follower 1 stopped, or after follower 2 started
    shown = [r.data["t_capture"] for r in records(l_rec, "video/recv")]
    old, live = [t for t in shown if t < t_stop1], [t for t in shown if t > t_start2]
    st = [dict(r.data["counters"]) for r in records(l_rec, "status/sent")]
    figures = {
        "captured": json.loads(attacker.log().splitlines()[0])["captured"],
        "shown_old": len(old),
        "shown_live": len(live),
        "oldest_shown_age_s": round(t_stop1 - min(old), 1) if old else None,
        "walk_after_start_s": round(t_walk - t_start2, 1),
        "leader_drops": {k: v for k, v in st[-1].items() if k.startswith("drop_")} if st else {},
    }
    print(json.dumps(figures))
    assert figures["captured"] >= 5, figures
    assert not old, f"the earlier session's video was shown as live: {figures}"
    assert len(live) >= 5, f"the live follower's video was not shown: {figures}"
