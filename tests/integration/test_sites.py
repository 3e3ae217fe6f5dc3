"""Issue 23: two sites, a router each, linked over TLS, from the files ``setup sites`` writes.

Site lab1: robot nao1, operators alice (drives nao1: a pair within the site) and bob
(drives nao2 at lab2: a pair across the sites). Site lab2: robot nao2, observer carol
(watches both). The two routers run as printed (``bipedtele router --config``), lab2's
linked to lab1's; robots, operators and the observer are real Zenoh sessions logged in
from their written profiles. Checked: each operator reaches its own robot only, across
the link too; the observer receives both robots' status across the link and reaches
nothing; with lab2's router killed, the pair within lab1 keeps exchanging and nao2 hears
nothing more.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

import pytest
import zenoh
from bipedtele.config import load_config
from bipedtele.sections import NetworkConfig
from bipedtele.tools.setup_fleet import write_sites
from bipedtele.zenohsession import open_session
from fleet_support import Tap, free_port, written_router

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]


def _until(cond: Callable[[], bool], step: Callable[[], None], timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        step()
        if cond():
            return True
        time.sleep(0.1)
    return cond()


def test_two_linked_sites_each_pair_its_own_and_one_site_down_leaves_the_other(tmp_path: Path) -> None:
    # Both routers on loopback: one port each; the written names are 127.0.0.1 (certificates too).
    p1, p2 = free_port(), free_port()
    out = write_sites(
        tmp_path / "s", {"lab1": "127.0.0.1", "lab2": "127.0.0.1"}, {"nao1": "lab1", "nao2": "lab2"},
        {"alice": ("lab1", ["nao1"]), "bob": ("lab1", ["nao2"])}, 7447, {"carol": ("lab2", ["nao1", "nao2"])},
    ).out  # fmt: skip
    port = {"lab1": p1, "lab2": p2}
    with ExitStack() as stack:
        stack.enter_context(written_router(out, "router-lab1/bipedtele.toml", p1, []))
        lab2 = stack.enter_context(written_router(out, "router-lab2/bipedtele.toml", p2, [f"tls/127.0.0.1:{p1}"]))

        def login(profile: str, site: str) -> zenoh.Session:
            ep = f'["tls/127.0.0.1:{port[site]}"]'
            net = load_config(out / profile, overrides=[f"network.connect={ep}"]).get(NetworkConfig)
            return stack.enter_context(open_session(net))

        nao1, nao2 = login("robot-nao1/bipedtele.toml", "lab1"), login("robot-nao2/bipedtele.toml", "lab2")
        alice, bob = login("operator-alice/nao1.toml", "lab1"), login("operator-bob/nao2.toml", "lab1")
        carol = login("observer-carol/bipedtele.toml", "lab2")
        cmd1, cmd2, fb1, st_c = Tap(), Tap(), Tap(), Tap()
        stack.callback(nao1.declare_subscriber("bipedtele/nao1/cmd", cmd1).undeclare)
        stack.callback(nao2.declare_subscriber("bipedtele/nao2/cmd", cmd2).undeclare)
        stack.callback(alice.declare_subscriber("bipedtele/nao1/feedback", fb1).undeclare)
        for r in ("nao1", "nao2"):
            stack.callback(carol.declare_subscriber(f"bipedtele/{r}/status", st_c).undeclare)

        def traffic() -> None:
            alice.put("bipedtele/nao1/cmd", b"alice->nao1")
            alice.put("bipedtele/nao2/cmd", b"alice->nao2")  # not hers: refused at lab1
            bob.put("bipedtele/nao2/cmd", b"bob->nao2")  # across the link
            bob.put("bipedtele/nao1/cmd", b"bob->nao1")  # not his
            nao1.put("bipedtele/nao1/feedback", b"nao1 fb")
            nao1.put("bipedtele/nao1/status", b"nao1 st")
            nao2.put("bipedtele/nao2/status", b"nao2 st")
            carol.put("bipedtele/nao2/cmd", b"carol->nao2")  # an observer: refused at lab2

        assert _until(lambda: cmd1.n(b"alice->nao1") >= 10 and cmd2.n(b"bob->nao2") >= 10
                      and st_c.n(b"nao1 st") >= 10 and st_c.n(b"nao2 st") >= 10, traffic, 30.0), (
            cmd1.by, cmd2.by, st_c.by)  # fmt: skip
        for _ in range(20):
            traffic()
        time.sleep(1.0)
        assert cmd2.n(b"alice->nao2") == 0 and cmd1.n(b"bob->nao1") == 0, (cmd1.by, cmd2.by)
        assert cmd2.n(b"carol->nao2") == 0, cmd2.by
        # lab2's router goes down: the pair within lab1 keeps exchanging, nao2 hears nothing more
        lab2.kill()
        lab2.wait(10)
        n2, a1, f1 = cmd2.n(b"bob->nao2"), cmd1.n(b"alice->nao1"), fb1.n(b"nao1 fb")
        for _ in range(30):
            traffic()
            time.sleep(0.05)
        time.sleep(0.5)
        assert cmd2.n(b"bob->nao2") == n2, "nao2 heard bob with its router down"
        assert cmd1.n(b"alice->nao1") >= a1 + 25 and fb1.n(b"nao1 fb") >= f1 + 25, (cmd1.by, fb1.by)
