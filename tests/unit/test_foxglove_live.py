"""The live view is guarded like the cockpit: a token, Host and Origin checks, loopback unless asked.

A real :class:`~bipedtele.recording.foxglovelive.LiveView` (its aiohttp server in its thread) fed as the
recorder feeds it, and real WebSocket clients (``tests/e2e/foxglove_client.py``): only the
token holder from no web page, Foxglove's web app or the server's own origin watches; the
others are refused before anything is sent (403) and get nothing. The e2e run with both
programs checks the same against a running leader (``tests/e2e/test_operator_side.py``).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent.parent / "e2e"))
from foxglove_client import Seen, watch

pytest.importorskip("aiohttp")
from bipedtele.recording.foxglovelive import LiveView, check_bind

pytestmark = pytest.mark.timeout(60)


@pytest.fixture(scope="module")
def live() -> Iterator[LiveView]:
    view = LiveView("127.0.0.1", 0, name="bipedtele b32b test")
    view.add_channel(1, "cmd/sent", "bipedtele.Command", "jsonschema", b'{"type": "object"}')
    stop = threading.Event()

    def feed() -> None:
        while not stop.is_set():
            view.log(1, b'{"ref": [0.05, 0.0]}', time.time_ns())
            stop.wait(0.01)

    th = threading.Thread(target=feed, daemon=True)
    th.start()
    yield view
    stop.set()
    th.join()
    view.close()


def _watch(url: str, **headers: str) -> Seen:
    return watch(url, 0.8, headers or None)


def test_the_token_holder_watches(live: LiveView) -> None:
    seen = _watch(live.url)
    assert seen.refused == 0 and seen.server["name"] == "bipedtele b32b test"
    assert seen.channels["cmd/sent"]["schemaName"] == "bipedtele.Command"
    assert seen.messages.get("cmd/sent", 0) > 5, seen.messages
    assert seen.first_payload["cmd/sent"] == {"ref": [0.05, 0.0]}
    assert _watch(live.url, Origin="https://app.foxglove.dev").messages  # Foxglove's web app


@pytest.mark.parametrize(
    ("why", "url", "headers", "counter"),
    [
        ("no token", "ws://127.0.0.1:{port}/", {}, "refused_token"),
        ("a wrong token", "ws://127.0.0.1:{port}/?token=AAAAAAAAAAAAAAAAAAAAAAAAAAAAAAAA", {}, "refused_token"),
        ("a foreign web page", "{url}", {"Origin": "https://evil.example.com"}, "refused_origin"),
        ("a page on another port", "{url}", {"Origin": "http://127.0.0.1:1"}, "refused_origin"),
        (
            "DNS rebinding",
            "{url}",
            {"Host": "evil.example.com:{port}", "Origin": "http://evil.example.com:{port}"},
            "refused_host",
        ),
    ],
)
def test_a_client_without_the_token_or_from_elsewhere_gets_nothing(
    live: LiveView, why: str, url: str, headers: dict[str, str], counter: str
) -> None:
    before = live.counters[counter]
    fill = {"port": str(live.port), "url": live.url}
    seen = _watch(url.format(**fill), **{k: v.format(**fill) for k, v in headers.items()})
    assert seen.refused == 403, (why, seen)
    assert not seen.server and not seen.channels and not seen.messages, (why, seen)
    assert live.counters[counter] == before + 1, (why, live.counters)


def test_a_non_loopback_bind_is_refused_unless_allowed() -> None:
    assert check_bind(("127.0.0.1", 8765), False) == ("127.0.0.1", 8765)
    assert check_bind(("localhost", 0), False) and check_bind(("::1", 0), False)
    for host in ("0.0.0.0", "192.168.1.5", "::", "robot.example.com"):
        with pytest.raises(ValueError, match="--allow-remote"):
            check_bind((host, 8765), False)
        assert check_bind((host, 8765), True) == (host, 8765)
    with pytest.raises(ValueError, match="--allow-remote"):
        LiveView("0.0.0.0", 0)
