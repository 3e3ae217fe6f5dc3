"""Try to join a robot's network as a Zenoh client and listen to its feedback.

    python tests/e2e/zclient.py --connect tls/127.0.0.1:7448 --ca ca.pem \
        [--cert c.pem --key c.key] [--user U --password P] [--seconds 2]

Prints one JSON line: ``{"opened": bool, "error": str | null, "feedback": n}`` where
``feedback`` counts the valid Feedback messages received in ``--seconds`` after the
session opened. Used by the two-host test to show who the router refuses.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from bipedtele.config import ConfigError
from bipedtele.drops import DropCounter
from bipedtele.messages import Feedback
from bipedtele.sections import NetworkConfig
from bipedtele.transport import Keys, MessageReceiver, open_session


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
    ap.add_argument("--timeout", type=float, default=3.0, help="session open timeout [s]")
    args = ap.parse_args(argv)
    net = NetworkConfig(
        mode="client", connect=[args.connect], tls_root_ca=args.ca, tls_cert=args.cert, tls_key=args.key,
        tls_mutual=bool(args.cert), user=args.user, password=args.password, timeout_s=args.timeout,
    )  # fmt: skip
    out: dict[str, object] = {"opened": False, "error": None, "feedback": 0}
    try:
        with open_session(net) as session:
            out["opened"] = True
            with MessageReceiver(session, Keys(args.robot_id).feedback, Feedback, DropCounter("zclient")) as rx:
                time.sleep(args.seconds)
                out["feedback"] = len(rx.drain())
    except ConfigError as exc:
        out["error"] = str(exc)
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
