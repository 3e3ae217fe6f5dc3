"""Press the cockpit's Release or Take button as the page does: ``python cockpit_hand.py URL release|take``.

Opens the cockpit's websocket with the printed address's token and the page's Origin,
waits for the server's hello, sends ``{"type": "hand", "release": ...}`` and stays 1 s.
Exit 0 when sent.
"""

from __future__ import annotations

import asyncio
import json
import sys
import urllib.parse

import aiohttp


async def press(url: str, release: bool) -> None:
    u = urllib.parse.urlsplit(url)
    base = f"{u.scheme}://{u.netloc}"
    async with (
        aiohttp.ClientSession() as session,
        session.ws_connect(f"{base}/ws?{u.query}", headers={"Origin": base}, timeout=10) as ws,
    ):
        hello = await ws.receive(timeout=10)
        assert "hello" in str(hello.data), hello
        await ws.send_str(json.dumps({"type": "hand", "release": release}))
        await asyncio.sleep(1.0)


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[2] not in ("release", "take"):
        sys.exit("usage: cockpit_hand.py URL release|take")
    asyncio.run(press(sys.argv[1], sys.argv[2] == "release"))
