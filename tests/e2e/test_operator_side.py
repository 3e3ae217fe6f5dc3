"""Issue 24 in one live run: a gamepad in the page drives the robot, the leader lacks every
Linux-only module, and both programs are watched live in Foxglove.

Router, sim follower (an obstacle straight ahead, the scene camera at 2 fps) and the leader
with ``--device gamepad`` run as separate processes on loopback, both with ``--foxglove
127.0.0.1:0``. The leader (and its cockpit's child process) runs in an interpreter that lacks
what Windows lacks (``windowslike/sitecustomize.py``: ``evdev``, ``pyudev``, ``fcntl``,
``termios``, ``resource``, ``pty``, ``tty``, ``grp``, ``pwd`` cannot be imported, ``os.nice``
is gone). Real chromium opens the printed cockpit address with a standard gamepad injected
into the page (``navigator.getGamepads``; its ``vibrationActuator`` keeps the effects it is
asked to play, as a browser hands them to the controller): stick forward with RB held for
11 s towards the obstacle, then RB let go. A Foxglove WebSocket client (protocol
``foxglove.sdk.v1``, ``foxglove_client.py``) watches each program meanwhile.

Checked, each by its own test:

- the leader ran, drove the robot and ended cleanly without the Linux-only modules;
- the commands carry the stick's speed through the device's mapping (``k_g`` times 0.98 of
  the workspace times the stick past the dead zone), and letting the dead-man go stops the
  robot within the watchdog (0.5 s);
- the rumble follows the handle force: every effect's strong magnitude is |force_v| / 8 N of
  a sample the leader recorded just before, and as the obstacle's fictitious force stops the
  robot the rumble rises well above its lowest of the walk (measured: 2.0 to 2.3 times);
- every channel of each program's recording was advertised live with the recording's own
  JSON Schema, and messages reached the client on every topic the recording wrote while it
  watched;
- a client without the token, or with the token from a foreign web page (``Origin``), is
  refused and gets nothing.
"""

from __future__ import annotations

import bisect
import json
import os
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from bipedtele.config.profile import load_config
from bipedtele.control.config import ControlConfig
from bipedtele.leader.parts import PadConfig
from e2e_support import HERE, Procs, free_port, records, start_follower, start_leader, start_router
from foxglove_client import Seen, watch
from mcap.reader import make_reader

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.browser]

BLOCKED = "evdev,pyudev,fcntl,termios,resource,pty,tty,grp,pwd"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]
# A box 0.2 m deep, 0.8 m wide, its near face 0.6 m ahead of the robot's start.
OBSTACLE = 'world.obstacles=[{shape="box", position=[0.7, 0.0, 0.25], size=[0.2, 0.8, 0.5]}]'
VIDEO = ["--set", "follower.camera_fps=2", "--set", 'follower.cameras=["scene"]']
STICK_Y = 0.6
WALK_S = 12.5
WATCHDOG_S = 0.5
FORCE_MAX_N = 8.0  # the gamepad's force limit: the page's rumble scale
WATCH_S = 8.0
ARTIFACTS = HERE.parent.parent / "artifacts"

INJECT = """
(() => {
  const pad = { axes: [0, 0, 0, 0], buttons: [], effects: [] };
  for (let i = 0; i < 17; i++) pad.buttons.push({ pressed: false, touched: false, value: 0 });
  const gp = {
    id: "Injected standard gamepad (test)", index: 0, connected: true, mapping: "standard", timestamp: 0,
    get axes() { return pad.axes.slice(); }, get buttons() { return pad.buttons; },
    vibrationActuator: { type: "dual-rumble",
      playEffect(type, params) { pad.effects.push({ t: Date.now() / 1000, type, ...params }); return Promise.resolve("complete"); } },
  };
  navigator.getGamepads = () => [gp, null, null, null];
  window.__pad = pad;
})();
"""


@dataclass
class Run:
    leader_rc: int
    leader_log: str
    attempts: list[str]
    rec: dict[str, Path]
    t_walk: float
    t_release: float
    effects: list[dict[str, Any]]
    label: str
    seen: dict[str, Seen] = field(default_factory=dict)  # role -> what its live view's client saw


def _drive(url: str) -> tuple[float, float, list[dict[str, Any]], str]:
    """The gamepad in the page: forward with RB held for WALK_S, then RB let go."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 950})
            page.add_init_script(INJECT)
            page.goto(url)
            deadline = time.monotonic() + 20.0
            while not page.evaluate("window.cockpit.padSent > 5 && window.cockpit.samplesReceived > 5"):
                assert time.monotonic() < deadline, "the page sends no pad state"
                page.wait_for_timeout(50)
            t_walk = time.time()
            page.evaluate(f"window.__pad.axes[1] = {-STICK_Y}; window.__pad.buttons[5].pressed = true;")
            page.wait_for_timeout(1000 * (WALK_S - 1.0))
            ARTIFACTS.mkdir(exist_ok=True)
            page.screenshot(path=str(ARTIFACTS / "cockpit_gamepad.png"))
            page.wait_for_timeout(1000)
            t_release = time.time()
            page.evaluate("window.__pad.buttons[5].pressed = false;")  # the stick still forward
            page.wait_for_timeout(2000)
            return t_walk, t_release, page.evaluate("window.__pad.effects"), page.locator("#pad-src").inner_text()
        finally:
            browser.close()


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: run scripts/bootstrap.sh --test (installs chromium)")
    folder = tmp_path_factory.mktemp("operator-side")
    procs = Procs(folder)
    ep = f"tcp/127.0.0.1:{free_port()}"
    rec = {"leader": folder / "leader.mcap", "follower": folder / "follower.mcap"}
    block_log = folder / "blocked.txt"
    env = {
        "PYTHONPATH": os.pathsep.join([str(HERE / "windowslike"), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
        "BIPEDTELE_BLOCK": BLOCKED,
        "BIPEDTELE_BLOCK_LOG": str(block_log),
    }
    fox = ["--foxglove", "127.0.0.1:0"]
    seen: dict[str, Seen] = {}

    def watching(role: str, url: str, headers: dict[str, str] | None = None) -> threading.Thread:
        th = threading.Thread(target=lambda: seen.__setitem__(role, watch(url, WATCH_S, headers)), daemon=True)
        th.start()
        return th

    try:
        start_router(procs, ep)
        follower = start_follower(procs, ep, [*VIDEO, "--set", OBSTACLE, *fox], record=rec["follower"])
        f_url = "ws://" + follower.wait_log(r"foxglove live view on ws://(\S+)", 30.0).group(1)
        leader = start_leader(
            procs, ep, ["--device", "gamepad", "--set", "leader.cockpit_port=0", *fox], record=rec["leader"], env=env
        )
        l_url = "ws://" + leader.wait_log(r"foxglove live view on ws://(\S+)", 30.0).group(1)
        url = leader.wait_log(r"cockpit: open (http://\S+)", 10.0).group(1)
        watchers = [
            watching("follower", f_url),
            watching("leader", l_url),
            watching("no token", l_url.split("?")[0]),
            watching("foreign origin", l_url, {"Origin": "https://evil.example.com"}),
        ]
        t_walk, t_release, effects, label = _drive(url)
        for th in watchers:
            th.join(30.0)
        assert leader.alive() and follower.alive(), leader.tail() + follower.tail()
        rc = leader.stop()
        assert follower.stop() == 0, follower.tail()
        attempts = block_log.read_text().split() if block_log.exists() else []
        yield Run(rc, leader.log(), attempts, rec, t_walk, t_release, effects, label, seen)
    finally:
        procs.close()


def test_the_leader_drives_the_robot_without_linux_only_modules(run: Run) -> None:
    assert run.leader_rc == 0, run.leader_log[-3000:]
    assert "Traceback" not in run.leader_log, run.leader_log[-3000:]
    assert "cockpit: open http://127.0.0.1:" in run.leader_log  # its child process served
    fbs = [r.data for r in records(run.rec["follower"], "feedback/sent")]
    assert sum(1 for d in fbs if d["state"] == "walking") > 100, {d["state"] for d in fbs}
    print(f"imports refused in the leader's processes: {sorted(set(run.attempts))}")


def test_the_stick_drives_through_the_mapping_and_the_dead_man_stops_the_robot(run: Run) -> None:
    assert "Injected standard gamepad" in run.label, run.label
    cfg = load_config("default")
    k_g, dz = cfg.get(ControlConfig).k_g, cfg.get(PadConfig).deadzone
    want = k_g[0] * 0.98 * 0.05 * (STICK_Y - dz) / (1 - dz)  # workspace 0.05 m
    cmds = records(run.rec["follower"], "cmd/recv")
    driving = [c.data for c in cmds if run.t_walk + 0.5 < c.t_recv < run.t_release]
    assert len(driving) > 500 and all(c["enable"] for c in driving), len(driving)
    assert all(abs(c["ref"][0] - want) < 0.01 * want and abs(c["ref"][1]) < 1e-6 for c in driving), (want, driving[0])
    fbs = [r.data for r in records(run.rec["follower"], "feedback/sent")]
    assert sum(1 for d in fbs if run.t_walk < d["t"] < run.t_release and d["state"] == "walking") > 100
    first_stop = next(c.t_recv for c in cmds if c.t_recv > run.t_release and not c.data["enable"])
    assert first_stop - run.t_release < WATCHDOG_S, first_stop - run.t_release
    assert not any(d["state"] == "walking" for d in fbs if d["t"] > first_stop + 1.0), "still walking"


def test_the_rumble_follows_the_handle_force_near_the_obstacle(run: Run) -> None:
    states = [(r.data["t"], r.data.get("force_v") or 0.0) for r in records(run.rec["leader"], "leader/state")]
    ts = [t for t, _ in states]
    walk, near = [], []
    assert run.effects
    for e in run.effects:
        assert e["type"] == "dual-rumble", e
        i = bisect.bisect_right(ts, e["t"]) - 1
        window = [abs(f) / FORCE_MAX_N for _, f in states[max(0, i - 60) : i + 1]]  # the leader's last 0.6 s
        assert window and min(window) - 0.02 <= e["strongMagnitude"] <= max(window) + 0.02, (e, window[:3], window[-3:])
        if run.t_walk + 1.0 < e["t"] < run.t_release:
            walk.append(e["strongMagnitude"])
        if run.t_release - 1.5 < e["t"] < run.t_release:
            near.append(e["strongMagnitude"])
    assert walk and near, (len(run.effects), run.t_walk, run.t_release)
    low, f_near = min(walk), sorted(near)[len(near) // 2]
    print(f"rumble: lowest of the walk {low:.3f}, at the obstacle {f_near:.3f} ({len(run.effects)} effects)")
    # the obstacle acts (its fictitious force, eq. 33), and the rumble rises with the force it adds
    f_t = [
        r.data.get("f_v_t") or 0.0 for r in records(run.rec["leader"], "leader/state") if r.data["t"] < run.t_release
    ]
    assert f_t[-1] > 3.0, f_t[-1]
    assert f_near > 0.1 and f_near > 1.5 * low, (low, f_near)


def _channels(path: Path) -> dict[str, tuple[str, bytes]]:
    """Topic -> (schema name, schema data) of a recording."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {
        ch.topic: (summary.schemas[ch.schema_id].name, summary.schemas[ch.schema_id].data)
        for ch in summary.channels.values()
    }


@pytest.mark.parametrize("role", ["leader", "follower"])
def test_a_foxglove_client_gets_every_channel_schema_and_messages(run: Run, role: str) -> None:
    seen = run.seen[role]
    assert seen.server.get("name", "").startswith(f"bipedtele {role}"), seen.server
    recorded = _channels(run.rec[role])
    assert recorded and set(recorded) <= set(seen.channels), sorted(set(recorded) - set(seen.channels))
    for topic, (name, data) in recorded.items():
        ch = seen.channels[topic]
        assert ch["encoding"] == "json" and ch["schemaEncoding"] == "jsonschema", ch
        assert ch["schemaName"] == name and json.loads(ch["schema"]) == json.loads(data), topic
    # every channel with messages in the recording while the client watched reached it
    t0, t1 = seen.t_open + 1.0, seen.t_close - 1.0
    with open(run.rec[role], "rb") as f:
        during = {ch.topic for _, ch, m in make_reader(f).iter_messages() if t0 < m.log_time / 1e9 < t1}
    assert during, "nothing recorded while the client watched"
    missing = {t for t in during if not seen.messages.get(t)}
    assert not missing, (missing, seen.messages)
    print(f"{role}: {len(seen.channels)} channels, messages {dict(sorted(seen.messages.items()))}")


@pytest.mark.parametrize("who", ["no token", "foreign origin"])
def test_a_foxglove_client_without_the_token_or_from_a_foreign_origin_gets_nothing(run: Run, who: str) -> None:
    seen = run.seen[who]
    assert not seen.channels and not seen.messages and not seen.server, (who, seen)
    assert seen.refused == 403, (who, seen.refused)
    assert run.seen["leader"].messages, "the token holder watched meanwhile"
