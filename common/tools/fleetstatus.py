"""``bipedtele status``: the fleet view, what an observer sees of the robots on the router.

::

    bipedtele status --config observer-carol/bipedtele.toml [--robot nao1 ...] [--seconds 3] [--json]

For each robot (``--robot``, else one per ``<id>.watch`` file in ``[network]
watch_key_dir``, else the profile's ``[robot] id``): who is present (liveliness tokens
``bipedtele/<id>/presence/<role>/<zid>``), and the newest
Status of its follower and of each leader, verified with the robot's watch key
(:func:`bipedtele.link.auth.watch_key`): the follower's state, the leader's state and
operator, and the leader's link figures (age of the newest feedback, feedback loss,
bit rate received). Status arrives at 2 Hz; ``--seconds`` is how long it listens.

Run by an observer (``observers_allowed`` on the router, ``bipedtele setup fleet
--observer``: receives, puts nothing), or with a leader's or a robot's profile for its own
robot (the watch key is derived from its message key). Exit 0 with the table (or one
JSON object with ``--json``); 1 when the router cannot be reached; 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bipedtele.cli import add_config_args, config_from_args
from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig, RobotConfig
from bipedtele.link.auth import MessageAuth, load_message_auth, load_watch_auths
from bipedtele.link.drops import DropCounter
from bipedtele.link.linkcheck import LinkError
from bipedtele.link.messages import Status
from bipedtele.link.receivers import MessageReceiver
from bipedtele.link.relink import control_name
from bipedtele.link.transport import Keys
from bipedtele.link.zenohsession import open_session

__all__ = ["RobotView", "add_status_parser", "fleet_view", "format_table", "watch_auths", "watched_robots"]

ROLES = ("follower", "leader", "observer")


@dataclass
class RobotView:
    """What ``bipedtele status`` saw of one robot.

    Attributes
    ----------
    robot : str
        The robot id.
    present : dict
        Role -> the Zenoh ids of its live presence tokens.
    follower : dict or None
        The follower's newest Status (``state``, ``text``, ``counters``), or None.
    leaders : dict
        Leader session id (hex) -> its newest Status (``state``, ``operator``, ``text``,
        ``counters``).
    verified : bool
        Whether a watch key verified the statuses (False: no key for this robot).
    dropped : dict
        Status messages refused, by reason (``bad_mac``: not this robot's watch key).
    """

    robot: str
    present: dict[str, list[str]] = field(default_factory=dict)
    follower: dict[str, Any] | None = None
    leaders: dict[str, dict[str, Any]] = field(default_factory=dict)
    verified: bool = False
    dropped: dict[str, int] = field(default_factory=dict)


def watched_robots(args_robots: list[str] | None, net: NetworkConfig, own: str) -> list[str]:
    """Return the robots to watch: those asked, else one per watch key file, else the profile's own."""
    if args_robots:
        return list(dict.fromkeys(args_robots))
    if net.watch_key_dir and Path(net.watch_key_dir).is_dir():
        found = sorted(p.stem for p in Path(net.watch_key_dir).glob("*.watch"))
        if found:
            return found
    return [own]


def watch_auths(net: NetworkConfig, robots: list[str], own: str) -> dict[str, MessageAuth]:
    """Return each robot's watch key (the own robot's derived from the message key)."""
    auths = load_watch_auths(net, robots)
    master = load_message_auth(net)
    if master is not None and own in robots and own not in auths:
        auths[own] = master.watch()
    return auths


def fleet_view(cfg: Any, robots: list[str] | None = None, seconds: float = 3.0) -> list[RobotView]:
    """Listen ``seconds`` on the profile's router and return one :class:`RobotView` per robot.

    Raises
    ------
    ConfigError
        Bad profile files or settings.
    LinkError
        The router cannot be reached.
    """
    net = cfg.get(NetworkConfig)
    own = cfg.get(RobotConfig).id
    ids = watched_robots(robots, net, own)
    auths = watch_auths(net, ids, own)
    views = {r: RobotView(r, verified=r in auths) for r in ids}
    mode = "client" if net.connect else "peer"
    with open_session(net, mode=mode, listen=[]) as session:
        drops = {r: DropCounter(f"status/{r}") for r in ids}
        receivers: dict[str, MessageReceiver[Status]] = {
            r: MessageReceiver(session, Keys(r).status, Status, drops[r], auth=auths.get(r)) for r in ids
        }
        try:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                for r, rx in receivers.items():
                    for got in rx.drain():
                        st = got.msg
                        entry = {"state": st.state, "text": st.text, "counters": dict(st.counters), "t": st.t}
                        if st.role == "follower":
                            views[r].follower = {**entry, "held_by": st.held_by}
                        else:
                            views[r].leaders[f"{st.sid:x}"] = {**entry, "operator": st.operator}
                time.sleep(0.1)
            # every robot's query at once (a bound observer may not ask with a wildcard for the robot)
            queries = {r: session.liveliness().get(f"{Keys(r).root}/presence/*/*", timeout=2.0) for r in ids}
            for r, replies in queries.items():
                for reply in replies:
                    if reply.ok is None:
                        continue
                    parts = str(reply.ok.key_expr).split("/")  # bipedtele/<id>/presence/<role>/<zid>
                    if len(parts) == 5 and parts[3] in ROLES:
                        views[r].present.setdefault(parts[3], []).append(parts[4])
        finally:
            for rx in receivers.values():
                rx.close()
        for r in ids:
            views[r].dropped = dict(drops[r].counts())
    return [views[r] for r in ids]


def _fmt_leader(lead: dict[str, Any]) -> str:
    c = lead["counters"]
    figs = []
    if "fb_age_ms" in c:
        figs.append(f"feedback age {c['fb_age_ms']} ms")
    if "fb_loss_ppm" in c:
        figs.append(f"loss {c['fb_loss_ppm'] / 1e4:.2f} %")
    if "rx_bps" in c:
        figs.append(f"rx {c['rx_bps'] / 1000:.0f} kbit/s")
    who = lead["operator"] or "?"
    return f"{who} ({lead['state']}{'; ' + ', '.join(figs) if figs else ''})"


def format_table(views: list[RobotView]) -> str:
    """Return the views as a table: one line per robot (and one per extra leader)."""
    lines = [f"{'robot':<12} {'follower':<44} leaders (state; link)"]
    for v in views:
        n_f = len(v.present.get("follower", []))
        fol = "absent" if not n_f else (v.follower["state"] if v.follower else "present, no status")
        if v.follower and v.follower.get("held_by"):
            fol += f", held by {v.follower['held_by']}"
        if v.follower and "control_link" in v.follower["counters"]:
            fol += f", control {control_name(v.follower['counters']['control_link'])}"
        leaders = [_fmt_leader(lead) for lead in v.leaders.values()] or (
            ["nobody"] if not v.present.get("leader") else [f"{len(v.present['leader'])} leader(s), no status"]
        )
        note = "" if v.verified else "  [no watch key: status unverified]"
        bad = {k: n for k, n in v.dropped.items() if n}
        if bad:
            note += f"  [status dropped: {', '.join(f'{k} {n}' for k, n in sorted(bad.items()))}]"
        lines.append(f"{v.robot:<12} {fol:<44} {leaders[0]}{note}")
        lines += [f"{'':<12} {'':<44} {extra}" for extra in leaders[1:]]
    return "\n".join(lines) + "\n"


def _run(args: argparse.Namespace) -> int:
    if not 0.5 <= args.seconds <= 60:
        raise ConfigError(f"--seconds {args.seconds:g}: allowed: 0.5 to 60")
    cfg = config_from_args(args)
    try:
        views = fleet_view(cfg, args.robot, args.seconds)
    except LinkError as exc:
        sys.stderr.write(f"status: {exc}\n")
        return 1
    if args.json:
        sys.stdout.write(json.dumps({"robots": [vars(v) for v in views]}) + "\n")
    else:
        sys.stdout.write(format_table(views))
    return 0


def add_status_parser(sub: Any) -> None:
    """``bipedtele status``: the fleet view."""
    p = sub.add_parser("status", help="the fleet view: robots on the router, who drives each, link figures")
    add_config_args(p)
    p.add_argument("--robot", action="append", metavar="ID", help="a robot to show (repeat; default: every watch key)")
    p.add_argument("--seconds", type=float, default=3.0, metavar="S", help="how long to listen (default 3)")
    p.add_argument("--json", action="store_true", help="one JSON object instead of the table")
    p.set_defaults(func=_run)
