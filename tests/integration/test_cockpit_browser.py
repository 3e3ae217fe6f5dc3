"""The cockpit in a real headless browser (Debian's chromium driven by playwright).

Video frames (real JPEGs) and telemetry are published from a thread as the leader loop
would; the page, opened at the printed address with its token, must show the frames, move
its plots and drive the server-side joystick. Without the token the browser gets 403; the
cookie set by the first load lets the page reload without it. A screenshot is kept in
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
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip
ARTIFACTS = Path(__file__).resolve().parents[2] / "artifacts"


def _sample(t: float, i: int) -> dict[str, object]:
    return {
        "t": t, "ref_v": 5.0 * math.sin(t), "eta_v": 4.0 * math.sin(t - 0.3),
        "z_e_v": 4.5 * math.sin(t - 0.2), "ref_w": 4.0 * math.cos(t),
        "eta_w": 3.5 * math.cos(t - 0.3), "z_e_w": 3.8 * math.cos(t - 0.2),
        "force_v": math.sin(2 * t), "force_w": 0.5 * math.cos(2 * t),
        "h1_ms": 150.0 + 20 * math.sin(t), "h2_ms": 180.0 + 30 * math.cos(0.7 * t),
        "alpha_m_v": 2.0 + 0.1 * math.sin(t), "alpha_m_w": 1.5, "s_r_v": 0.8, "s_r_w": 0.6,
        "T": 0.6 + 0.05 * math.sin(t), "eps": 0.5, "state": "walking", "link": "ok",
        "watchdog": "ok", "falls": 0, "passes_done": i // 200, "sonar_left_m": 0.8,
    }  # fmt: skip


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


@pytest.fixture
def fed_server() -> Iterator[CockpitServer]:
    server = CockpitServer(telemetry_hz=25.0).start()
    stop = threading.Event()

    def feed() -> None:  # a stand-in for the leader loop: 200 Hz samples, 15 fps video
        i = 0
        deadline = time.monotonic() + 60.0
        while not stop.is_set() and time.monotonic() < deadline:
            t = time.time()
            server.publish_sample(_sample(t, i))
            if i % 13 == 0:
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
            natural = page.evaluate("document.querySelector('img[data-camera=head]').naturalWidth")
            assert natural == 320
            assert page.locator("#st-link b").inner_text() == "ok"
            assert "sonar_left_m" in page.locator("#other").inner_text()  # unknown key as text
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
        finally:
            browser.close()
    assert errors == []
    assert (ARTIFACTS / "cockpit.png").stat().st_size > 10_000
