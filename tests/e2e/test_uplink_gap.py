"""A cellular uplink's gap, end to end: the README's two hosts, the robot's uplink dead for 3.5 s in every 12.5 s.

``bench/internet.py``'s machinery (three namespaces named ``b33*``, TLS, logins, ACL,
message key; the pilot drives): robot | link-emu | router + operator, 40 ms each way, the
robot -> router direction replaying a mahimahi trace (2 Mbit/s for 9 s, nothing for
3.5 s, repeated) through a 256 kB drop-tail queue; the downlink is free, so commands keep
reaching the robot through each gap. 18 s of the pilot: at least one whole gap.

- No "ACL" wording: the router refused nothing. Before, the follower's status and video
  queued in the gap arrived first when it ended, with no acknowledgement for far longer
  than the reach check's window, and the leader warned "commands not reaching the robot:
  refused by the router's ACL?" at every gap's end.
- No backlog of the robot's own: with the leader's status at 10 Hz (the in-flight cap's
  acknowledgements) the first fresh feedback arrives within 0.5 s of the path's return, and
  of what was sent once the follower could know, the first feedback to arrive is fresh.
- The blind operator does not drive: the leader stops the robot once its newest feedback
  is older than ``blind_stop_s`` (1.5 s), within 0.5 s more (plus the downlink's 40 ms),
  and it walks again after the gap.
"""

from __future__ import annotations

import os
import secrets
import shutil
from pathlib import Path
from typing import Any

import pytest
from test_internet import _load_bench

SECONDS = 18.0
GAP_AT_MS, PERIOD_MS = 9000, 12500


def _trace(path: Path) -> Path:
    """2 Mbit/s (an MTU every 6 ms) until 9 s, then nothing until 12.5 s; mahimahi repeats it."""
    path.write_text("".join(f"{ms}\n" for ms in range(6, GAP_AT_MS, 6)) + f"{PERIOD_MS}\n")
    return path


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_gap_of_the_robots_uplink_names_no_acl_and_stops_the_blind_operator(tmp_path: Path) -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root: network namespaces and the link emulator's raw sockets")
    for tool in ("ip", "openssl", "ss"):
        if shutil.which(tool) is None:
            pytest.skip(f"needs `{tool}` (scripts/bootstrap.sh --test installs iproute2 and openssl)")
    mod = _load_bench()
    setup = tmp_path / "setup"
    commands = mod.setup_two_hosts(setup)
    trace = _trace(tmp_path / "gap.mahi")
    cond = mod.Condition(
        "gap",
        "uplink gap 3.5 s in 12.5 s",
        "lan",
        (
            "--forward",
            "const:40ms",
            "--backward",
            "const:40ms",
            "--rate-forward",
            f"mahimahi:{trace}",
            "--queue-forward",
            "256kB",
        ),
    )
    tag = f"b33{secrets.token_hex(1)[0]}"
    ack = ("--set", "leader.status_rate_hz=10")  # acknowledgements for the in-flight cap
    r: dict[str, Any] = mod.run_condition(
        cond, "split", SECONDS, setup, commands, tmp_path / "run", seed=3, tag=tag, leader_extra=ack
    )
    print(mod.row_line(r))
    print("  " + mod.emu_line(r.get("linkemu")))
    print("  " + str(r.get("leader_summary")))
    assert "error" not in r, r["error"]
    leader_log = (Path(r["run_dir"]) / "leader.log").read_text(errors="replace")
    g = r["gap"]
    assert any(x["length_s"] >= 2.5 for x in g["gaps"]), f"no gap of the feedback at the leader: {g}"
    assert "ACL" not in leader_log, [ln for ln in leader_log.splitlines() if "ACL" in ln]
    assert g["blind_stops"] >= 1, g
    # the robot stops within blind_stop_s + 0.5 s of the newest feedback's send, plus the
    # 40 ms the stopping command travels
    assert all(s <= 1.5 + 0.5 + 0.04 for s in g["stop_after_newest_fb_s"]), g
    assert r["distance_m"] > 0.3, r["distance_m"]  # it walked
    # no backlog of the robot's own: the follower's in-flight cap held what it sent in the gap
    # to a feedback per 0.2 s, so a fresh one (at most 0.5 s old) arrives within 0.5 s of the
    # path's return
    long = [x for x in g["gaps"] if x["length_s"] >= 2.5]
    assert all(x["fresh_after_s"] is not None and x["fresh_after_s"] <= 0.5 for x in long), long
    # and of what the follower sent once it could know (0.5 s into the gap: a round trip and
    # a status period), the first feedback to arrive is fresh: no feedback left as a probe
    # (before, one did and arrived 1.4 s old); what was in flight when the gap began is
    # measured apart (inflight_age_s)
    assert all(x["first_late_age_s"] is not None and x["first_late_age_s"] <= 0.5 for x in long), long
