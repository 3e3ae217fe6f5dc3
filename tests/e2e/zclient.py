"""Try to join a robot's network as a Zenoh client and listen to its feedback.

    python tests/e2e/zclient.py --connect tls/127.0.0.1:7448 --ca ca.pem \
        [--cert c.pem --key c.key] [--user U --password P] [--seconds 2]

Prints one JSON line: ``{"opened": bool, "error": str | null, "feedback": n, "put_cmd": m}``
where ``feedback`` counts the valid Feedback messages received in ``--seconds`` after the
session opened, and ``put_cmd`` the stop commands (``enable = false``) it published on
``cmd`` meanwhile (``--put-cmd``; at most 50 Hz). Used by the two-host test to show whom
the router refuses and that only the leader's identity may command the robot.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.drops import DropCounter
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.messages import Command, Feedback
from bipedtele.link.receivers import MessageReceiver
from bipedtele.link.transport import Keys, Publishers, Stamper
from bipedtele.link.zenohsession import open_session


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connect", required=True)
    ap.add_argument("--robot-id", default="nao1")
    ap.add_argument("--ca", default="")
    ap.add_argument("--cert", default="")
    ap.add_argument("--key", default="")
    ap.add_argument("--user", default="")
    ap.add_argument("--password", default="")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--put-cmd", action="store_true", help="publish stop commands while listening")
    ap.add_argument("--timeout", type=float, default=3.0, help="session open timeout [s]")
    args = ap.parse_args(argv)
    net = NetworkConfig(
        mode="client",
        connect=[args.connect],
        tls_root_ca=args.ca,
        tls_cert=args.cert,
        tls_key=args.key,
        tls_mutual=bool(args.cert),
        user=args.user,
        password=args.password,
        timeout_s=args.timeout,
    )
    out: dict[str, object] = {"opened": False, "error": None, "feedback": 0, "put_cmd": 0}
    try:
        with open_session(net) as session:
            out["opened"] = True
            keys = Keys(args.robot_id)
            with (
                MessageReceiver(session, keys.feedback, Feedback, DropCounter("zclient")) as rx,
                Publishers(session, keys) as pubs,
            ):
                stamper, n = Stamper(), 0
                end = time.monotonic() + args.seconds
                while time.monotonic() < end:
                    if args.put_cmd:
                        pubs.cmd.put(stamper.make(Command, enable=False))
                        n += 1
                    time.sleep(0.02)
                out["feedback"] = len(rx.drain())
                out["put_cmd"] = n
                out["sid"] = stamper.sid
    except ConfigError as exc:
        out["error"] = str(exc)
    except LinkError as exc:  # refused or unreachable: which one, as far as TLS and Zenoh tell
        out["error"] = str(exc)
        out["kind"] = exc.kind
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
