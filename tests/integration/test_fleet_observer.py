"""Issue 23: observers and the fleet view on a real router, from the files ``setup fleet`` writes.

The router runs as printed (TLS with mutual certificates, passwords, the written ACL).
Robots and leaders are real Zenoh sessions logged in from their written profiles, publishing
Status and video the way the programs do (:class:`bipedtele.link.transport.Publishers` with the
robot's message key: video and status under its watch key) and declaring presence.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
import zenoh
from bipedtele.config.profile import load_config
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.auth import MacError, MessageAuth, load_message_auth, read_key_file, watch_key
from bipedtele.link.messages import Command, Status, VideoFrame, encode
from bipedtele.link.transport import Keys, Publishers, declare_presence
from bipedtele.link.zenohsession import open_session
from bipedtele.tools.setup_fleet import write_fleet
from fleet_support import Tap, free_port, written_router

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

ROBOTS = ["nao1", "nao2"]
OPERATORS = {"alice": ("nao1",), "bob": ("nao2",)}
OBSERVERS = {"carol": ("nao1", "nao2"), "dave": ("nao2",)}


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[Path]:
    port = free_port()
    out = write_fleet(tmp_path / "f", "127.0.0.1", ROBOTS, OPERATORS, port, OBSERVERS).out
    with written_router(out, "router/bipedtele.toml", port):
        yield out


def _status(role: str, seq: int, state: str, text: str, counters: dict[str, int], **who: str) -> Status:
    return Status(
        sid=0x1234 if role == "leader" else 0x5678,
        seq=seq,
        t=time.time(),
        role=role,
        state=state,
        counters=counters,
        text=text,
        **who,
    )


def test_the_observer_watches_its_robots_and_commands_none(fleet: Path) -> None:
    with ExitStack() as stack:

        def login(profile: str) -> tuple[zenoh.Session, NetworkConfig]:
            net = load_config(fleet / profile).get(NetworkConfig)
            return stack.enter_context(open_session(net)), net

        pubs = {}
        for r, lead in (("nao1", "operator-alice/nao1.toml"), ("nao2", "operator-bob/nao2.toml")):
            rs, rnet = login(f"robot-{r}/bipedtele.toml")
            ls, lnet = login(lead)
            stack.enter_context(declare_presence(rs, Keys(r), "follower"))
            stack.enter_context(declare_presence(ls, Keys(r), "leader"))
            pubs[r] = (
                stack.enter_context(Publishers(rs, Keys(r), auth=load_message_auth(rnet))),
                stack.enter_context(Publishers(ls, Keys(r), auth=load_message_auth(lnet))),
            )
        carol, dave = login("observer-carol/bipedtele.toml")[0], login("observer-dave/bipedtele.toml")[0]
        carol_again = login("observer-carol/bipedtele.toml")[0]  # her puts (a session hears its own)
        # what each observer receives (raw, key by key: the ACL refuses a wildcard subscription),
        # and what nao1's follower receives on its command key
        seen = {"carol": Tap(), "dave": Tap()}
        for who, session in (("carol", carol), ("dave", dave)):
            for r in ROBOTS:
                for k in ("video", "status", "cmd", "feedback", "clock"):
                    stack.callback(session.declare_subscriber(f"bipedtele/{r}/{k}", seen[who]).undeclare)
        f1_cmd = Tap()
        rs1 = login("robot-nao1/bipedtele.toml")[0]
        stack.callback(rs1.declare_subscriber("bipedtele/nao1/cmd", f1_cmd).undeclare)
        l1_status = Tap()  # what alice's side hears on nao1's status key
        stack.callback(
            login("operator-alice/nao1.toml")[0].declare_subscriber("bipedtele/nao1/status", l1_status).undeclare
        )

        stop = threading.Event()

        def publish() -> None:
            seq = 0
            while not stop.wait(0.1):
                seq += 1
                for r, (fp, lp) in pubs.items():
                    who = "alice" if r == "nao1" else "bob"
                    fp.status.put(_status("follower", seq, "walking", f"robot={r}", {"falls": 0}, held_by=who))
                    lp.status.put(
                        _status(
                            "leader",
                            seq,
                            "running",
                            "clock: ntp",
                            {"fb_age_ms": 12, "fb_loss_ppm": 1000, "rx_bps": 64000},
                            operator=who,
                        )
                    )
                    fp.video.put(
                        VideoFrame(
                            sid=0x5678, seq=seq, t=time.time(), camera="head", width=2, height=2, jpeg=b"\xff\xd8jpeg"
                        )
                    )

        th = threading.Thread(target=publish, daemon=True)
        th.start()
        try:
            # the fleet view, as printed for carol (both robots), from another working folder
            res = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "bipedtele.cli",
                    "status",
                    "--config",
                    "observer-carol/bipedtele.toml",
                    "--seconds",
                    "2",
                    "--json",
                ],
                capture_output=True,
                text=True,
                timeout=60,
                cwd=fleet,
            )
            assert res.returncode == 0, res.stderr
            views = {v["robot"]: v for v in json.loads(res.stdout)["robots"]}
            assert sorted(views) == ROBOTS
            for r, who in (("nao1", "alice"), ("nao2", "bob")):
                v = views[r]
                assert v["verified"] and v["follower"]["state"] == "walking" and v["follower"]["held_by"] == who, v
                assert [lead["operator"] for lead in v["leaders"].values()] == [who], v
                assert len(v["present"]["follower"]) >= 1 and len(v["present"]["leader"]) == 1, v
                assert not any(v["dropped"].values()), v
            table = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "bipedtele.cli",
                    "status",
                    "--config",
                    "observer-carol/bipedtele.toml",
                    "--seconds",
                    "1.5",
                ],
                capture_output=True,
                text=True,
                timeout=60,
                cwd=fleet,
            )
            assert table.returncode == 0 and "alice (running; feedback age 12 ms" in table.stdout, table.stdout
            assert "walking, held by alice" in table.stdout, table.stdout
            # carol tries to command nao1: the router drops her put, and her watch key cannot sign one
            wk = read_key_file(str(fleet / "observer-carol/secrets/nao1.watch"), "watch_key_dir")
            forged = MessageAuth(wk).sign(encode(Command(sid=9, seq=1, t=time.time())), "bipedtele/nao1/cmd")
            # a status she forges is valid under the watch key: only the router's ACL keeps it out
            fake = _status("follower", 10**6, "walking", "forged", {})
            forged_status = MessageAuth(wk).sign(encode(fake), "bipedtele/nao1/status")
            for _ in range(30):
                carol_again.put("bipedtele/nao1/cmd", forged)
                carol_again.put("bipedtele/nao1/status", forged_status)
            time.sleep(1.0)
            # dave's fleet view: nao2 only (his one watch key); asked for nao1 he gets nothing of it
            res = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "bipedtele.cli",
                    "status",
                    "--config",
                    "observer-dave/bipedtele.toml",
                    "--robot",
                    "nao1",
                    "--seconds",
                    "1",
                    "--json",
                ],
                capture_output=True,
                text=True,
                timeout=60,
                cwd=fleet,
            )
            assert res.returncode == 0, res.stderr
            (v,) = json.loads(res.stdout)["robots"]
            assert v["robot"] == "nao1" and not v["verified"] and v["follower"] is None and not v["present"], v
        finally:
            stop.set()
            th.join(5)
        assert sum(f1_cmd.by.values()) == 0, f1_cmd.by
        assert l1_status.by_key["bipedtele/nao1/status"] > 0 and l1_status.n(forged_status) == 0
        master = load_message_auth(load_config(fleet / "robot-nao1/bipedtele.toml").get(NetworkConfig))
        assert master is not None and watch_key(read_key_file(str(fleet / "robot-nao1/secrets/message.key"))) == wk
        with pytest.raises(MacError, match="bad_mac"):
            master.verify(forged, "bipedtele/nao1/cmd")
        # carol received both robots' video and status, dave nao2's only; neither any command or feedback
        for who, robots in (("carol", ROBOTS), ("dave", ["nao2"])):
            got = seen[who].by_key
            for r in ROBOTS:
                want = r in robots
                assert (got[f"bipedtele/{r}/video"] > 0) == want and (got[f"bipedtele/{r}/status"] > 0) == want, (
                    who,
                    got,
                )
            assert not [k for k in got if k.endswith(("/cmd", "/feedback", "/clock"))], (who, got)


def test_written_fleet_on_a_real_router_each_operator_reaches_its_robots_only(tmp_path: Path) -> None:
    """The router as printed (TLS, mutual certificates, the written ACL), robots and operators
    logged in from their written profiles: alice's puts reach nao1 and never nao2; bob reaches both."""
    port = free_port()
    out = write_fleet(
        tmp_path / "g", "127.0.0.1", ["nao1", "nao2"], {"alice": ("nao1",), "bob": ("nao2", "nao1")}, port
    ).out
    with written_router(out, "router/bipedtele.toml", port), ExitStack() as stack:

        def login(profile: str) -> zenoh.Session:
            net = load_config(out / profile).get(NetworkConfig)
            return stack.enter_context(open_session(net))

        robots = {r: login(f"robot-{r}/bipedtele.toml") for r in ROBOTS}
        got = {r: Tap() for r in ROBOTS}
        for r, session in robots.items():
            stack.callback(session.declare_subscriber(f"bipedtele/{r}/cmd", got[r]).undeclare)
        alice, bob = login("operator-alice/nao1.toml"), login("operator-bob/nao2.toml")
        time.sleep(1.0)  # the subscriptions reach the router
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and not (got["nao1"].by[b"a1"] >= 20 and got["nao2"].by[b"b2"] >= 20):
            for _ in range(10):
                alice.put("bipedtele/nao1/cmd", b"a1")
                alice.put("bipedtele/nao2/cmd", b"a2")  # not hers: the router drops it
                bob.put("bipedtele/nao2/cmd", b"b2")
            time.sleep(0.2)
        time.sleep(0.5)
        assert got["nao1"].by[b"a1"] >= 20, got["nao1"].by  # alice reaches nao1
        assert got["nao2"].by[b"b2"] >= 20, got["nao2"].by  # bob reaches nao2
        assert got["nao2"].by[b"a2"] == 0 and got["nao1"].by[b"a2"] == 0, (got["nao1"].by, got["nao2"].by)
        assert got["nao1"].by[b"b2"] == 0  # bob's put on nao2's key is nao2's only
