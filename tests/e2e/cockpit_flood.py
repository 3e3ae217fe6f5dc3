"""Floods of the leader's browser cockpit, for ``test_adversary_cockpit.py`` (127.0.0.1 only).

Run as a program (every loop bounded in count and time)::

    python tests/e2e/cockpit_flood.py idle  --port P [--n 3000] [--seconds 20]
    python tests/e2e/cockpit_flood.py brute --port P [--requests 20000] [--seconds 8] [--workers 64]

``idle``   opens ``--n`` connections that each send half a request head and nothing more,
           holds them ``--seconds`` and reports, once a second, how many the server has
           closed (or refused) so far; for each still open at the end, how long ago the
           server's kernel acknowledged its half head (one never acknowledged never got
           past the server's full accept queue: the server holds nothing for it).
``brute``  guesses tokens as fast as it can over keep-alive connections (``--workers`` at
           once, reconnecting when the server closes one) and counts the answers by status.

Each prints one JSON line with what it did and saw.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import resource
import secrets
import selectors
import socket
import struct
import sys
import time
from collections import Counter
from typing import Any

HOST = "127.0.0.1"
MAX_N = 10_000
MAX_SECONDS = 60.0
CONNECT_S = 10.0  #: a connect not done by then (its SYN unanswered) is left out


def _raise_nofile(need: int) -> None:
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = need + 64 if hard == resource.RLIM_INFINITY else min(hard, need + 64)
    if soft < want:
        resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))


def _unacked(s: socket.socket) -> bool:
    """Whether what ``s`` sent is still unacknowledged (``tcpi_unacked`` of Linux's ``tcp_info``).

    A half head the server's kernel never acknowledged: the connection never completed
    there (its final ACK was dropped while the accept queue was full and it waits in
    ``SYN_RECV``), so the server holds no descriptor for it and cannot close it.
    """
    try:
        info = s.getsockopt(socket.IPPROTO_TCP, socket.TCP_INFO, 28)
    except OSError:
        return False
    return len(info) >= 28 and struct.unpack_from("I", info, 24)[0] > 0


def idle(port: int, n: int, seconds: float) -> dict[str, Any]:
    """Half-sent request heads on ``n`` connections; when the server closes them."""
    _raise_nofile(n)
    head = f"GET / HTTP/1.1\r\nHost: {HOST}:{port}\r\nUser-Agent: slow".encode()
    socks: list[socket.socket] = []
    failed: Counter[str] = Counter()
    t0 = time.monotonic()
    for _ in range(n):
        s = socket.socket()
        s.setblocking(False)
        try:
            s.connect((HOST, port))
        except BlockingIOError:
            pass
        except OSError as exc:
            failed[type(exc).__name__] += 1
            s.close()
            continue
        socks.append(s)
    open_s = time.monotonic() - t0
    # One loop: a socket that becomes writable sends half a head (once) and is then watched
    # for the server's close; one that has not connected within CONNECT_S is left out.
    sel = selectors.DefaultSelector()  # epoll: thousands of descriptors
    for s in socks:
        sel.register(s, selectors.EVENT_WRITE)
    pending = set(socks)
    alive = set(socks)
    acked_at: dict[socket.socket, float] = {}  # when the server's kernel acknowledged the half head
    sent = 0
    closed_at: list[float] = []
    ack_to_close: list[float] = []
    timeline: list[tuple[float, int]] = []
    end = t0 + min(seconds, MAX_SECONDS)
    next_mark = time.monotonic()
    while time.monotonic() < end and alive:
        now = time.monotonic()
        if pending and now - t0 > CONNECT_S:
            for s in pending:
                sel.unregister(s)
                alive.discard(s)
            pending.clear()
        if now >= next_mark:
            timeline.append((round(now - t0), len(socks) - len(alive)))
            acked_at.update((s, now) for s in alive - pending if s not in acked_at and not _unacked(s))
            next_mark += 1.0
        for key, _ in sel.select(0.05):
            s = key.fileobj
            assert isinstance(s, socket.socket)
            if s in pending:
                pending.discard(s)
                sel.modify(s, selectors.EVENT_READ)
                try:
                    s.send(head)
                    sent += 1
                except OSError as exc:  # refused at once (reset): seen as closed next
                    failed[type(exc).__name__] += 1
                continue
            try:
                data = s.recv(4096)
            except OSError:
                data = b""
            if not data:  # closed (or reset) by the server
                sel.unregister(s)
                alive.discard(s)
                t = time.monotonic()
                closed_at.append(t - t0)
                if s in acked_at:
                    ack_to_close.append(t - acked_at[s])
    now = time.monotonic()
    timeline.append((round(now - t0), len(socks) - len(alive)))
    sel.close()
    acked_at.update((s, now) for s in alive if s not in acked_at and not _unacked(s))
    held = sorted((round(now - acked_at[s], 1) for s in alive if s in acked_at), reverse=True)
    out = {
        "opened": len(socks),
        "sent": sent,
        "open_s": round(open_s, 2),
        "connect_failed": dict(failed),
        "closed": len(socks) - len(alive),
        "still_open": len(alive),
        "still_open_unacked": len(alive) - len(held),
        "still_open_held_s": held[:50],
        "ack_to_close_max_s": round(max(ack_to_close), 2) if ack_to_close else None,
        "timeline": timeline,
        "closed_p50_s": sorted(closed_at)[len(closed_at) // 2] if closed_at else None,
    }
    for s in socks:
        s.close()
    return out


async def _brute(port: int, total: int, seconds: float, workers: int) -> dict[str, Any]:
    status: Counter[str] = Counter()
    sent = [0]
    end = time.monotonic() + min(seconds, MAX_SECONDS)

    async def worker() -> None:
        reader: asyncio.StreamReader | None = None
        writer: asyncio.StreamWriter | None = None
        while time.monotonic() < end and sent[0] < total:
            try:
                if writer is None:
                    reader, writer = await asyncio.wait_for(asyncio.open_connection(HOST, port), 2.0)
                assert reader is not None
                sent[0] += 1
                writer.write(
                    f"GET /?token={secrets.token_urlsafe(24)} HTTP/1.1\r\nHost: {HOST}:{port}\r\n\r\n".encode()
                )
                line = await asyncio.wait_for(reader.readline(), 2.0)
                if not line:
                    raise ConnectionResetError("closed")
                code = line.split(b" ")[1].decode() if line.count(b" ") >= 1 else "?"
                length, close = 0, False
                while True:
                    h = await asyncio.wait_for(reader.readline(), 2.0)
                    if h in (b"\r\n", b""):
                        break
                    k, _, v = h.decode("latin-1").partition(":")
                    if k.lower() == "content-length":
                        length = int(v.strip())
                    elif k.lower() == "connection" and v.strip().lower() == "close":
                        close = True
                if length:
                    await asyncio.wait_for(reader.readexactly(length), 2.0)
                status[code] += 1
                if close:
                    raise ConnectionResetError("server closes")
            except (OSError, asyncio.IncompleteReadError, TimeoutError) as exc:
                if not isinstance(exc, ConnectionResetError) or str(exc) != "server closes":
                    status[f"err_{type(exc).__name__}"] += 1
                if writer is not None:
                    writer.close()
                    with contextlib.suppress(Exception):
                        await writer.wait_closed()
                reader = writer = None
                await asyncio.sleep(0.001)
        if writer is not None:
            writer.close()

    t0 = time.monotonic()
    await asyncio.gather(*(worker() for _ in range(workers)))
    elapsed = time.monotonic() - t0
    return {
        "sent": sent[0],
        "elapsed_s": round(elapsed, 2),
        "rate_hz": round(sent[0] / elapsed, 1),
        "status": dict(status),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("attack", choices=["idle", "brute"])
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--n", type=int, default=3000)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--requests", type=int, default=20_000)
    ap.add_argument("--workers", type=int, default=64)
    a = ap.parse_args(argv)
    if not 0 < a.n <= MAX_N or not 0 < a.seconds <= MAX_SECONDS or not 0 < a.requests <= 100_000:
        ap.error(f"allowed: --n up to {MAX_N}, --seconds up to {MAX_SECONDS:g}, --requests up to 100000")
    if a.attack == "idle":
        out = idle(a.port, a.n, a.seconds)
    else:
        _raise_nofile(a.workers)
        out = asyncio.run(_brute(a.port, a.requests, a.seconds, min(a.workers, 512)))
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
