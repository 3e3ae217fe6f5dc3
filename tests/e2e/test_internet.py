"""The real internet, short: the README's two hosts on the per-packet link emulator (issue 19).

``bipedtele setup two-hosts`` once; each run copies the three folders into three "hosts"
(network namespaces) and runs the README's three commands there (TLS, logins, ACL, message
key, the ``links = "split"`` layout the setup writes), with ``bipedtele link-emu`` between
one host and the other two (``bench/internet.py``'s machinery, which prints the full
90 s table; this file asserts behaviour on short runs):

(a) the shipped intercontinental trace + 1 % loss both ways (operator | emulator | router +
    robot), 30 s: no watchdog stop, the robot walks, and each message's delay beyond what
    the emulator applied stays small (see ``EXCESS_P99_MS``);
(b) a LAN robot with a 300 kbit/s uplink (64 kB queue) and video on (robot | emulator |
    router + operator), 30 s: no fresh command dropped as too old, feedback h2 p99 under
    300 ms once the uplink budget has estimated the path (its first cut, + 2 s to drain), h2
    under 1 s in the start before it (its one overshoot), video at >= 1 frame/s, and the
    leader's samples say ``capacity-limited``;
(c) a 3 s outage both ways on the intercontinental path: the robot stops within 0.6 s of the
    last command it received (it cannot know of the cut earlier: h1 after the cut), walks
    again within 1 s of the path's return, and no command sent before the return is applied
    after it.

(b) failed before the uplink budget judged h2's growth every tick, started video small and
bounded a frame's burst (h2 p99 1.69 s after 8 s), and before the sessions turned Zenoh's
shared memory off (frames over 3 kB skipped the emulated link, so the cap never saw them).

Delays are true one-way delays: every namespace shares this machine's clock, so a message's
receive time minus its send stamp is its delay (the follower's ``cmd/recv``, the leader's
``feedback/recv``).

``BIPEDTELE_TEST_LINKS=single`` runs the same checks on the old one-connection transport
(profiles rewritten to ``links = "single"``), to see which claims it fails.
"""

from __future__ import annotations

import importlib.util
import os
import secrets
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from e2e_support import HERE

REPO = HERE.parent.parent
LINKS = os.environ.get("BIPEDTELE_TEST_LINKS", "split")
SECONDS = 30.0
STARTUP_S = 8.0  # (a): the excess is counted after it; (b): the start's h2 too
# (b) The uplink budget's start grows video x1.3 a second until the path queues; the leader's
# 1 s mean of h2 shows the queue about 0.75 s late, so the one overshoot before its first
# estimate of the path queued the feedback 150-350 ms in the runs so far (146-346 ms peaks).
# The defect this guards: seconds of lag (p99 1.69 s after 8 s before the budget existed).
START_MAX_MS = 1000.0

# (a) Bound on the p99 of each message's delay beyond the emulator's own (trace) delay at
# its send time. Without loss that excess is this machine's scheduling: the emulator
# (Python) and the three programs share two cores with the simulator's cameras. The 90 s
# no-loss run of bench/internet.py (split layout, video on) measured its p99 at 67 ms (h1)
# and 53 ms (h2). The issue allows the lossy run's p99 60 ms above the no-loss run's, so
# 70 + 60 ms. A lost segment on one reliable connection costs a retransmission at the real
# round trip (>= 360 ms): at 1 % loss the single-link transport's excess p99 was 592 ms
# (h1) and 471 ms (h2) in the same bench.
EXCESS_P99_MS = 130.0


def _load_bench() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_internet", REPO / "bench" / "internet.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["bench_internet"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> tuple[ModuleType, Path, dict[str, list[str]]]:
    """The bench module and one ``setup two-hosts`` (skips where namespaces cannot be made)."""
    if os.geteuid() != 0:
        pytest.skip("needs root: network namespaces and the link emulator's raw sockets")
    for tool in ("ip", "openssl", "ss"):
        if shutil.which(tool) is None:
            pytest.skip(f"needs `{tool}` (scripts/bootstrap.sh --test installs iproute2 and openssl)")
    probe = f"bt-probe-{secrets.token_hex(2)}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True, timeout=20)
    if r.returncode != 0:
        pytest.skip(f"cannot create network namespaces: {r.stderr.strip()}")
    subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=20)
    mod = _load_bench()
    out = tmp_path_factory.mktemp("internet") / "setup"
    return mod, out, mod.setup_two_hosts(out)


def _run(
    bench: tuple[ModuleType, Path, dict[str, list[str]]], cond: Any, run_dir: Path, seconds: float = SECONDS
) -> dict[str, Any]:
    mod, setup_out, commands = bench
    res: dict[str, Any] = mod.run_condition(
        cond, LINKS, seconds, setup_out, commands, run_dir, seed=3, startup_s=STARTUP_S
    )
    print(mod.row_line(res))
    print("  " + mod.emu_line(res.get("linkemu")))
    print("  " + str(res.get("leader_summary")))
    assert "error" not in res, res["error"]
    return res


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_lossy_intercontinental_path(bench: Any, tmp_path: Path) -> None:
    mod = bench[0]
    cond = mod.conditions()["loss1"]
    r = _run(bench, cond, tmp_path / "run")
    lost = r["linkemu"]["forward"]["dropped"]["loss"] + r["linkemu"]["backward"]["dropped"]["loss"]
    assert lost > 20, f"the emulator lost only {lost} frames: the loss was not exercised"
    assert r["watchdog_stops"] == 0, r
    assert r["passes"] >= 1 or r["distance_m"] >= 1.0, r
    for h in ("h1", "h2"):
        ex = r[f"{h}_excess_ms"]
        assert ex["n"] > 200, ex
        assert ex["p99"] <= EXCESS_P99_MS, (
            f"{h}: p99 {ex['p99']:.0f} ms beyond the emulator's delay (bound {EXCESS_P99_MS:g}); "
            f"{h} p50/p99/max {r[f'{h}_ms']}"
        )


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_capped_robot_uplink_with_video(bench: Any, tmp_path: Path) -> None:
    mod = bench[0]
    cond = mod.conditions()["lan300-video"]
    r = _run(bench, cond, tmp_path / "run")
    assert r["linkemu"]["forward"]["queue_bytes_max"] > 0, "the 300 kbit/s cap never queued: not exercised"
    assert r["cmd_too_old"] == 0, r["follower_counters"]
    # the steady state: from the budget's first estimate of the path (+ its drain)
    h2 = r["h2_ms_after_estimate"]
    assert r["first_estimate_s"] is not None, "the uplink budget never estimated the capped path"
    assert h2["n"] > 200, (r["first_estimate_s"], h2)
    assert h2["p99"] < 300.0, f"feedback h2 p50/p99/max after the first estimate ({r['first_estimate_s']} s): {h2}"
    # the start: its growth overshoots the cap once before that estimate (a fifth, about a
    # second: 150-350 ms), never seconds
    start = r["h2_ms_start"]
    assert start["max"] is None or start["max"] < START_MAX_MS, f"feedback h2 in the start: {start}"
    assert r["video_fps"] >= 1.0, r["video_fps"]
    assert r["link_fraction"]["capacity-limited"], f"the leader never said capacity-limited: {r['link_states_seen']}"


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_outage_stops_and_resumes_on_fresh_commands(bench: Any, tmp_path: Path) -> None:
    mod = bench[0]
    cond = mod.conditions(outage_at=14.0)["outage"]  # ~8-10 s into the pilot's run: walking
    r = _run(bench, cond, tmp_path / "run", seconds=24.0)
    o = r["outage"]
    assert o["walking_at_cut"], f"the robot was not walking when the path was cut: {o}"
    # The robot cannot know of the cut before its watchdog runs out: it stops within 0.6 s
    # of the last command it received (the watchdog, 0.5 s, plus a control tick), which is
    # h1 (about 0.18 s here) after the cut: 0.68-0.72 s from the cut in the runs so far.
    assert o["stop_after_last_command_s"] is not None and o["stop_after_last_command_s"] <= 0.6, o
    assert o["stop_latency_s"] is not None and o["stop_latency_s"] <= 0.6 + 0.3, o
    # 3 s without feedback stop the robot from the leader too (blind_stop_s, 1.5 s): then it
    # walks again within 1 s of fresh feedback and the operator's handle move
    if o["move_after_return_s"] is None:
        assert o["restart_latency_s"] is not None and o["restart_latency_s"] <= 1.0, o
    else:
        assert o["restart_after_move_s"] is not None and o["restart_after_move_s"] <= 1.0, o
    assert o["stale_applied"] == 0, o
