"""A control scheme from another distribution: one module and one entry point, nothing else.

``tests/plugins/toy/toy_scheme.py`` (``toy-damped``: the robot's measured speed fed back, a
fixed extra handle damping) is registered by one line of the toy distribution's
``entry_points.txt``; nothing in bipedtele names it. With that folder on ``PYTHONPATH``:

- the contract checker (:func:`bipedtele.control.schemes.check.check_scheme`) passes over
  every registered scheme, the toy included;
- ``bipedtele compare --schemes toy-damped`` runs it on the reduced model, paired against
  the paper, and its runs differ from the paper's (its own law ran);
- without the plugin, ``--schemes toy-damped`` is refused in one line naming the allowed ones.

The demo with it is tests/e2e/test_toy_scheme_demo.py.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

PLUGIN = Path(__file__).resolve().parents[1] / "plugins" / "toy"
CLI = [sys.executable, "-m", "bipedtele.cli"]

_CHECK_ALL = """
import json
from bipedtele.control.schemes import scheme_names
from bipedtele.control.schemes.check import check_scheme
for name in scheme_names():
    check_scheme(name)
print(json.dumps(scheme_names()))
"""


def _env(plugin: bool) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if plugin:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PLUGIN), os.environ.get("PYTHONPATH", "")) if p)
    return env


def _run(args: list[str], plugin: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=90, env=_env(plugin), cwd="/")


@pytest.mark.timeout(120)
def test_the_contract_checker_passes_over_every_registered_scheme_the_toy_included() -> None:
    res = _run([sys.executable, "-c", _CHECK_ALL])
    assert res.returncode == 0, res.stderr[-3000:]
    names = json.loads(res.stdout.strip().splitlines()[-1])
    assert {"paper", "paper-constant", "pd-worst-case", "pd-measured", "wave", "tdpa", "toy-damped"} <= set(names)


@pytest.mark.timeout(120)
def test_compare_runs_the_toy_scheme_on_the_reduced_model() -> None:
    args = [
        "compare",
        "--walker-runs",
        "0",
        "--runs",
        "3",
        "--duration",
        "5",
        "--schemes",
        "toy-damped",
        "--regimes",
        "trace",
        "--no-margin",
        "--json",
        "-",
    ]
    res = _run([*CLI, *args])
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout)
    # paired against the baseline, the paper's cell of the factorial grid (docs/schemes.md)
    assert set(out["schemes"]) == {"scheduled/ze", "toy-damped"}
    toy = out["cells"]["trace"]["toy-damped"]
    assert toy["n"] + toy["unstable"] == 3
    assert toy["unstable"] == 0
    for metric in ("forward_error", "turn_error", "forward_effort"):
        assert math.isfinite(toy[metric]["mean"])
    # paired against the paper on the same operators and delays: the toy's own law ran
    assert toy["forward_effort"]["vs_baseline"]["mean"] != 0.0
    refused = _run([*CLI, *args], plugin=False)
    assert refused.returncode == 2
    assert "--schemes toy-damped: allowed: paper" in refused.stderr
