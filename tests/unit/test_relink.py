"""Which link carries control, which layouts are watched, how the fleet view says it; no role over UDP alone.

The reopening itself runs against real processes in tests/e2e/test_udp_link_heal.py.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
import zenoh
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.acl import access_control_json, stream_protocols
from bipedtele.link.relink import control_code, control_link, control_name, describe_control, relink_control
from bipedtele.tools.fleetstatus import RobotView, format_table

BE, REL = zenoh.Reliability.BEST_EFFORT, zenoh.Reliability.RELIABLE


def _link(dst: str, prio: tuple[int, int] | None, rel: zenoh.Reliability) -> SimpleNamespace:
    """What ``session.info.links()`` gives: the fields the choice reads."""
    return SimpleNamespace(dst=dst, priorities=prio, reliability=rel)


SPLIT = [
    _link("tls/r:7447?prio=0-4;rel=1", (0, 4), REL),
    _link("udp/r:7447?prio=1-2;rel=0", (1, 2), BE),
    _link("tls/r:7447?prio=5-7;rel=1", (5, 7), REL),
]


def test_the_split_layouts_control_link_is_the_udp_one_not_the_status_link_that_also_holds_priority_1() -> None:
    assert control_link(SPLIT) is SPLIT[1]
    assert describe_control(SPLIT) == "udp"
    assert control_code(describe_control(SPLIT)) == 1


def test_control_moved_onto_the_status_link_reads_shared() -> None:
    moved = [SPLIT[0], SPLIT[2]]  # the UDP link lost: Zenoh sends control on the status link
    assert control_link(moved) is SPLIT[0]
    assert describe_control(moved) == "tls (shared)"
    assert control_code(describe_control(moved)) == 3
    assert describe_control([_link("tcp/r:7447", None, REL)]) == "tcp (shared)"  # single
    assert describe_control([]) == "none" and control_code("none") == 0


def test_split_tcp_control_link() -> None:
    links = [SPLIT[0], _link("tls/r:7447?prio=1-2;rel=0", (1, 2), BE), SPLIT[2]]
    assert describe_control(links) == "tls" and control_code("tls") == 2


@pytest.mark.parametrize(
    ("net", "want"),
    [
        (NetworkConfig(mode="client", connect=["tls/r:7447"], links="split"), "udp"),
        (NetworkConfig(mode="client", connect=["tcp/r:7447"], links="split"), "udp"),
        (NetworkConfig(mode="client", connect=["tls/r:7447"], links="split-tcp"), "tls"),
        (NetworkConfig(mode="client", connect=["tls/r:7447"], links="single"), ""),
        (NetworkConfig(mode="router", listen=["tls/0.0.0.0:7447"], links="split"), ""),
        (NetworkConfig(mode="peer", links="split"), ""),
    ],
)
def test_only_clients_of_a_split_layout_watch_their_control_link(net: NetworkConfig, want: str) -> None:
    assert relink_control(net) == want


def test_the_fleet_view_names_the_followers_control_link() -> None:
    view = RobotView(
        "nao1",
        present={"follower": ["z"]},
        follower={"state": "walking", "text": "", "counters": {"control_link": 3}, "t": 0.0, "held_by": ""},
        verified=True,
    )
    assert "control shared link" in format_table([view])
    view.follower["counters"]["control_link"] = 1  # type: ignore[index]
    assert "walking, control udp" in format_table([view])
    assert control_name(2) == "tcp/tls"


def test_roles_hold_only_for_sessions_opened_on_a_stream_link(tmp_path: Path) -> None:
    """A session over the router's UDP listener alone (no certificate possible) matches no role."""
    creds = tmp_path / "creds.txt"
    creds.write_text("alice:a\nnao1:n\n")
    net = NetworkConfig(
        mode="router",
        listen=["tls/0.0.0.0:7447"],
        links="split",
        credentials_file=str(creds),
        publishers_allowed=["alice"],
        followers_allowed=["nao1"],
        routers_allowed=["router-b"],
    )
    acl = access_control_json(net)
    assert acl is not None
    roles = [s for s in acl["subjects"] if "usernames" in s]
    assert roles and all(s["link_protocols"] == ["tls"] for s in roles), roles
    routers = [s for s in acl["subjects"] if "cert_common_names" in s]
    assert routers == [{"id": "routers", "cert_common_names": ["router-b"]}]
    assert stream_protocols(["tls/0.0.0.0:7447", "udp/0.0.0.0:7447"]) == ["tls"]
    assert stream_protocols(["udp/0.0.0.0:7447"]) == []  # nothing else to ask for
    plain = access_control_json(net, ["udp/0.0.0.0:7447"])
    assert plain is not None and all("link_protocols" not in s for s in plain["subjects"])
