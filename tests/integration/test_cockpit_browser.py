"""The cockpit in a real headless browser (Debian's chromium driven by playwright).

Video frames (real JPEGs) and telemetry are published from a thread as the leader loop
would; the page, opened at the printed address with its token, must show the frames, move
its plots and drive the server-side joystick. Without the token the browser gets 403; the
cookie set by the first load lets the page reload without it; with no frame for longer than
the video age bound the page hides the last one and says so. A screenshot is kept in
``artifacts/cockpit.png``.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from bipedtele.leader.cockpit import CockpitServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
ARTIFACTS = Path(__file__).resolve().parents[2] / "artifacts"


def _sample(t: float, i: int) -> dict[str, object]:
    return {
        "t": t,
        "ref_v": 5.0 * math.sin(t),
        "eta_v": 4.0 * math.sin(t - 0.3),
        "z_e_v": 4.5 * math.sin(t - 0.2),
        "ref_w": 4.0 * math.cos(t),
        "eta_w": 3.5 * math.cos(t - 0.3),
        "z_e_w": 3.8 * math.cos(t - 0.2),
        "force_v": math.sin(2 * t),
        "force_w": 0.5 * math.cos(2 * t),
        "h1_ms": 150.0 + 20 * math.sin(t),
        "h2_ms": 180.0 + 30 * math.cos(0.7 * t),
        "alpha_m_v": 2.0 + 0.1 * math.sin(t),
        "alpha_m_w": 1.5,
        "s_r_v": 0.8,
        "s_r_w": 0.6,
        "T": 0.6 + 0.05 * math.sin(t),
        "eps": 0.5,
        "state": "walking",
        "link": "ok",
        "watchdog": 0,
        "held_by": "alice",
        "hand": "drive",
        "me": "dave",
        "falls": 0,
        "passes_done": i // 200,
        "sonar_left_m": 0.8,
        "fb_age_ms": 312.4,
        "loss_pct": 1.25,
        "rx_kbps": 850.2,
        "tx_kbps": 900.0,
        "video_fps": 9.8,
        "video_quality": 60,
    }


def _jpeg(i: int) -> bytes:
    img = np.zeros((240, 320, 3), np.uint8)
    img[:, :, 1] = (i * 7) % 255
    cv2.putText(img, f"frame {i}", (40, 130), cv2.FONT_HERSHEY_SIMPLEX, 1.4, (255, 255, 255), 3)
    ok, buf = cv2.imencode(".jpg", img)
    assert ok
    return buf.tobytes()


def _wait_for(page: Any, expression: str, timeout_ms: float) -> None:
    """Poll ``expression`` in the page until it is true (playwright's own
    ``wait_for_function`` evaluates strings with ``eval``, which the page's
    Content-Security-Policy forbids, as it should)."""
    deadline = time.monotonic() + timeout_ms / 1000.0
    while not page.evaluate(expression):
        if time.monotonic() > deadline:
            pytest.fail(f"page: {expression!r} still false after {timeout_ms / 1000:g} s")
        page.wait_for_timeout(50)


VIDEO_PAUSED = threading.Event()  # the feeder publishes no frame while set


@pytest.fixture
def fed_server() -> Iterator[CockpitServer]:
    VIDEO_PAUSED.clear()
    server = CockpitServer(telemetry_hz=25.0).start()
    stop = threading.Event()

    def feed() -> None:  # a stand-in for the leader loop: 200 Hz samples, 15 fps video
        i = 0
        deadline = time.monotonic() + 60.0
        while not stop.is_set() and time.monotonic() < deadline:
            t = time.time()
            server.publish_sample(_sample(t, i))
            if i % 13 == 0 and not VIDEO_PAUSED.is_set():
                server.publish_video("head", _jpeg(i), t)
            i += 1
            time.sleep(0.005)

    thread = threading.Thread(target=feed, daemon=True)
    thread.start()
    try:
        yield server
    finally:
        stop.set()
        thread.join(5)
        server.stop()


@pytest.mark.timeout(90)
def test_cockpit_in_headless_chromium(fed_server: CockpitServer) -> None:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: run scripts/bootstrap.sh --test (installs chromium)")
    from playwright.sync_api import sync_playwright

    server = fed_server
    errors: list[str] = []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.on("pageerror", lambda e: errors.append(str(e)))
            # The page runs under its own Content-Security-Policy: it must not break it.
            page.on("console", lambda m: errors.append(m.text) if "Content Security Policy" in m.text else None)
            refused = page.goto(server.base_url)  # the address without its token
            assert refused is not None and refused.status == 403
            page.goto(server.url)
            assert server.url == f"{server.base_url}?token={server.token}"

            # Video frames arrive and are decoded; plots receive points.
            _wait_for(page, "window.cockpit.framesShown >= 3 && window.cockpit.plotPoints > 50", 20_000)
            first = page.evaluate("({f: cockpit.framesShown, p: cockpit.plotPoints})")
            _wait_for(page, f"cockpit.framesShown > {first['f'] + 2} && cockpit.plotPoints > {first['p'] + 50}", 20_000)
            assert page.locator("img[data-camera=head]").count() == 1
            # a decoded frame is 320 px wide (read once, it raced the next frame's load: 0 px
            # while a new frame's source is being decoded; a clean-clone CI run failed on it)
            _wait_for(page, "document.querySelector('img[data-camera=head]').naturalWidth === 320", 10_000)
            assert page.locator("#st-link b").inner_text() == "ok"
            # The link's figures, and its states in words.
            assert page.locator("#st-age b").inner_text() == "312 ms"
            assert page.locator("#st-loss b").inner_text() == "1.3 %"
            assert page.locator("#st-rx b").inner_text() == "850 of 900 kbit/s"
            assert page.locator("#st-video b").inner_text() == "9.8 fps, q60"
            words = page.evaluate(
                "[{link: 'lost', link_lost_s: 3.24}, {link: 'no-follower'}, {link: 'capacity-limited'}]"
                ".map((s) => cockpit.linkWords(s))"
            )
            assert words == ["link lost for 3.2 s", "no follower", "capacity-limited"]
            assert "sonar_left_m" in page.locator("#other").inner_text()  # unknown key as text
            # A zero watchdog count is green; the robot is held by another operator (hand-over)
            assert page.locator("#st-watchdog b").inner_text() == "0"
            assert page.locator("#st-watchdog").get_attribute("data-state") == "ok"
            assert page.locator("#st-hand b").inner_text() == "held by alice: ask for release"
            hands = page.evaluate(
                "[{hand: 'drive', held_by: 'dave', me: 'dave'}, {hand: 'released', held_by: ''},"
                " {hand: 'released', held_by: 'bob', me: 'dave'}].map((s) => cockpit.handWords(s)[0])"
            )
            assert hands == ["you (dave) hold it", "released: free", "released; held by bob"]
            assert not server.released()
            page.locator("#hand-btn").click()  # Release
            deadline = time.monotonic() + 5.0
            while not server.released() and time.monotonic() < deadline:
                time.sleep(0.02)
            assert server.released() and server.stats["hand_messages"] == 1
            assert server.stats["frames_pushed"] >= 3 and server.stats["clients"] == 1
            assert server.joystick() is None

            # Drag the joystick up and to the right: forward and turn.
            box = page.locator("#joystick").bounding_box()
            assert box is not None
            cx, cy = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            radius = 0.4 * box["width"]
            t_before_drag = time.time()
            page.mouse.move(cx, cy)
            page.mouse.down()
            page.mouse.move(cx + 0.3 * radius, cy - 0.6 * radius, steps=8)
            page.wait_for_timeout(300)
            joy = server.joystick()
            assert joy is not None
            x, y, t_joy = joy
            assert x == pytest.approx(0.3, abs=0.05) and y == pytest.approx(0.6, abs=0.05)
            assert t_before_drag <= t_joy <= time.time()  # stamped by the server, during the drag
            ARTIFACTS.mkdir(exist_ok=True)
            page.screenshot(path=str(ARTIFACTS / "cockpit.png"))
            # Held still: the page keeps re-sending the position (a heartbeat).
            page.wait_for_timeout(400)
            joy_held = server.joystick()
            assert joy_held is not None and joy_held[2] > t_joy
            page.mouse.up()
            page.wait_for_timeout(300)
            joy = server.joystick()
            assert joy is not None and joy[:2] == (0.0, 0.0)  # release returns to centre

            # Bad input from a browser: dropped and counted, the page keeps working.
            bad_before = server.stats["bad_messages"]
            page.evaluate(
                """() => new Promise((done) => {
                    const w = new WebSocket(`ws://${location.host}/ws`);
                    w.onopen = () => {
                        w.send("not json");
                        w.send(JSON.stringify({type: "joy", x: 5, y: 0}));
                        w.send(JSON.stringify({type: "joy", x: "a", y: 0}));
                        w.send(new Uint8Array([1, 2, 3]));
                        setTimeout(() => { w.close(); done(); }, 200);
                    };
                })"""
            )
            page.wait_for_timeout(200)
            assert server.stats["bad_messages"] == bad_before + 4
            shown = page.evaluate("cockpit.framesShown")
            _wait_for(page, f"cockpit.framesShown > {shown}", 10_000)

            # Reload without the token in the address: the cookie of the first load serves.
            connections = server.stats["connections"]
            page.goto(server.base_url)
            _wait_for(page, "window.cockpit.wsOpen && window.cockpit.framesShown >= 1", 20_000)
            assert server.stats["connections"] > connections

            # No frame younger than the bound (3 s): the old one is not left up as live.
            img = "document.querySelector('img[data-camera=head]')"
            assert page.evaluate(f"!{img}.hidden")
            VIDEO_PAUSED.set()
            t_pause = time.monotonic()
            _wait_for(page, f"{img}.hidden", 10_000)
            assert time.monotonic() - t_pause > 2.5  # not before the bound
            assert "no live video" in page.locator("figure figcaption").inner_text()
            VIDEO_PAUSED.clear()
            _wait_for(page, f"!{img}.hidden", 10_000)
        finally:
            browser.close()
    assert errors == []
    assert (ARTIFACTS / "cockpit.png").stat().st_size > 10_000


COURSE = [(0.9, -0.2, 0.14), (1.8, 0.2, 0.1), (2.7, -0.2, 0.14)]


def _map_sample(t: float) -> dict[str, object]:
    """The robot as reported, and the leader predictor's two ghosts ahead of it on its heading."""
    yaw = 0.3 + 0.05 * math.sin(t)
    x, y = 1.2 + 0.02 * math.sin(t), 0.1
    ahead = {
        f"{name}_{k}": v
        for name, d in (("pred", 0.35), ("ahead", 0.7))
        for k, v in (("x", x + d * math.cos(yaw)), ("y", y + d * math.sin(yaw)), ("yaw", yaw))
    }
    return {
        "t": t,
        "pose_x": x,
        "pose_y": y,
        "pose_yaw": yaw,
        **ahead,
        "ahead_dt": 0.18,
        "h1_ms": 180.0,
        "h2_ms": 200.0,
    }


@pytest.mark.timeout(90)
def test_cockpit_map_shows_the_course_the_path_and_the_predicted_ghosts() -> None:
    """The predictive display: the hello carries the course, the map draws the obstacles, the
    reported path and pose, and the ghost of the predicted present pose where the sample puts
    it (its colour at its position on the canvas) and the pose h1 ahead."""
    if not Path(CHROMIUM).exists():
        pytest.fail(f"{CHROMIUM} is missing: run scripts/bootstrap.sh --test (installs chromium)")
    from playwright.sync_api import sync_playwright

    server = CockpitServer(telemetry_hz=25.0, course=COURSE).start()
    stop = threading.Event()

    def feed() -> None:
        deadline = time.monotonic() + 60.0
        while not stop.is_set() and time.monotonic() < deadline:
            server.publish_sample(_map_sample(time.time()))
            time.sleep(0.01)

    thread = threading.Thread(target=feed, daemon=True)
    thread.start()
    errors: list[str] = []
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            try:
                page = browser.new_page(viewport={"width": 1400, "height": 900})
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.on("console", lambda m: errors.append(m.text) if "Content Security Policy" in m.text else None)
                page.goto(server.url)
                _wait_for(
                    page, "cockpit.map.ghostDrawn && cockpit.map.draws > 3 && cockpit.map.path.length > 1", 20_000
                )
                got = page.evaluate(
                    """() => {
                        const m = cockpit.map;
                        m.draw();  // the latest sample, drawn now: read the pixels it made
                        const g = m.canvas.getContext("2d");
                        const px = (p) => { const [x, y] = m.toCanvas(p.x, p.y);
                            return Array.from(g.getImageData(Math.round(x), Math.round(y), 1, 1).data); };
                        return {obstacles: m.obstacles, ghost: px(m.ghost), ahead: m.ahead !== null,
                                robotCentre: px(m.pose), obstacle: px({x: m.obstacles[2][0], y: m.obstacles[2][1]}),
                                ghostPose: m.ghost, width: m.canvas.width};
                    }"""
                )
                ARTIFACTS.mkdir(exist_ok=True)
                page.locator("#map").screenshot(path=str(ARTIFACTS / "cockpit_map.png"))
            finally:
                browser.close()
    finally:
        stop.set()
        thread.join(5)
        server.stop()
    assert errors == []
    assert got["obstacles"] == [list(o) for o in COURSE]
    assert got["ghost"][:3] == [0xF0, 0xB4, 0x29]  # the amber ghost, filled, at the predicted pose
    assert got["obstacle"][:3] == [0x8B, 0x94, 0x9E]
    assert got["robotCentre"][:3] != [0xF0, 0xB4, 0x29]  # the reported pose is elsewhere
    assert got["ahead"] and got["width"] > 200
    assert got["ghostPose"]["x"] == pytest.approx(1.2 + 0.35 * math.cos(0.3), abs=0.05)
