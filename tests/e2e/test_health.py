"""``bipedtele health --role router|follower|leader`` against a running setup."""

from __future__ import annotations

import re

import pytest
from e2e_support import (
    NO_VIDEO,
    Procs,
    client_args,
    free_port,
    start_follower,
    start_leader,
    start_router,
    walking_script,
)


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(120)
def test_health_roles_against_running_setup(procs: Procs) -> None:
    ep = f"tcp/127.0.0.1:{free_port()}"
    start_router(procs, ep)
    start_follower(procs, ep, NO_VIDEO)
    leader = start_leader(procs, ep, walking_script(0.0))
    fast = ["--set", "network.timeout_s=2"]
    checks = {
        role: procs.start(f"health-{role}", ["health", *client_args(ep), *fast, "--role", role, "--timeout", "5"])
        for role in ("router", "follower", "leader")
    }
    for role, p in checks.items():
        assert p.popen.wait(timeout=30) == 0, (role, p.log())
        assert re.search(rf"^healthy: .*{role}", p.log(), re.M), p.log()

    # unhealthy answers: no leader any more; no router at an endpoint
    assert leader.stop() == 0
    gone = procs.start("health-gone", ["health", *client_args(ep), *fast, "--role", "leader", "--timeout", "1"])
    nobody = f"tcp/127.0.0.1:{free_port()}"
    no_router = procs.start(
        "health-norouter", ["health", *client_args(nobody), "--set", "network.timeout_s=1", "--role", "router"]
    )
    assert gone.popen.wait(timeout=30) == 1, gone.log()
    assert "unhealthy: no leader present" in gone.log()
    assert no_router.popen.wait(timeout=30) == 1, no_router.log()
    assert "unhealthy:" in no_router.log()
