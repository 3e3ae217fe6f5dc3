"""One job per room (issue 22, issue 34 item 5): module and function sizes, and ``# fmt: skip``.

Sizes. The product's folders (``common/``, ``leader/``, ``follower/``, ``configs/``,
``docker/``, ``bench/``; tests are not measured) are read with :mod:`ast`. No module of any
of them over 600 lines, no function over 80. A function's size is ``end_lineno - lineno + 1``
(its ``def`` line to its last line, decorators not counted); methods and nested functions
count on their own, named ``Class.method`` or ``outer.inner``. :data:`KNOWN` lists the
offenders allowed for now (the test prints them); a new offender fails, and so does an
entry of :data:`KNOWN` that is no longer one, so the list only shrinks.

``# fmt: skip``. A line kept out of ``ruff format`` is allowed only where a table needs it:
a constant laid out in rows that the formatter would put one item per line. Today that is
one file, :data:`FMT_SKIP_TABLES`: ``leader/cockpit/protocol.py``, whose ``SAMPLE_KEYS``
lists the cockpit's telemetry keys one row per group (the loop's variables, delays and
damping, the link and status, the run's counts, the poses), in the order of the key table
of docs/cockpit.md. Other tables sit in files whose other ``# fmt: skip`` lines are not
tables (``common/acl.py``'s ``_ROUTER_MESSAGES``, ``bench/recording.py``'s sample keys):
those files, and every other file that had any when this rule came, are in
:data:`FMT_SKIP_KNOWN` with their count (470 lines in 134 files; 481 in 136 before, the
cockpit server's and the Poincare map's modules reformatted instead). A count may only go
down: a file over its count, or a file in neither list with one, fails; so does an entry
above the file's present count (lower it, so that the entry stays a ratchet). The comments
(``fmt: skip`` and ``fmt: off``) are read with :mod:`tokenize` in the product's folders,
``tests/``, ``scripts/`` and ``docs/``.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: The folders measured (the package's and the programs' around it).
PARTS = ("common", "leader", "follower", "configs", "docker", "bench")
#: The folders whose formatter-skip comments (:data:`_FMT_COMMENT`) are counted.
FMT_PARTS = (*PARTS, "tests", "scripts", "docs")
#: Longest module of any folder of :data:`PARTS` [lines].
MAX_MODULE_LINES = 600
#: Longest function or method [lines].
MAX_FUNCTION_LINES = 80

#: Offenders not yet split: ``path`` (a module) or ``path:qualname`` (a function) -> why.
#: No function since issue 22's last splits; these modules since the rule covers every folder.
KNOWN: dict[str, str] = {
    "bench/internet.py": "the internet bench: its rows, runs and report to be split by job",
}

#: Files whose formatter-skip lines keep a table's rows -> how many, and which table.
FMT_SKIP_TABLES: dict[str, tuple[int, str]] = {
    "leader/cockpit/protocol.py": (1, "SAMPLE_KEYS, the cockpit's telemetry keys one row per group"),
}
#: Every other file with formatter-skip lines when this rule came -> the most it may keep.
FMT_SKIP_KNOWN: dict[str, int] = {
    "bench/adversary.py": 11,
    "bench/e2e.py": 12,
    "bench/fleet.py": 13,
    "bench/flood.py": 8,
    "bench/internet.py": 11,
    "bench/leader.py": 3,
    "bench/pilot.py": 3,
    "bench/recording.py": 5,
    "bench/transport.py": 2,
    "common/acl.py": 5,
    "common/auth.py": 3,
    "common/cli.py": 1,
    "common/control/inference.py": 1,
    "common/foxglovelive.py": 4,
    "common/foxglovews.py": 2,
    "common/linkevents.py": 1,
    "common/linklayout.py": 1,
    "common/node.py": 6,
    "common/recording.py": 2,
    "common/schemas.py": 6,
    "common/sections.py": 2,
    "common/session.py": 1,
    "common/shapers.py": 2,
    "common/tools/demo.py": 6,
    "common/tools/demoplan.py": 2,
    "common/tools/fleetstatus.py": 1,
    "common/tools/linkemu.py": 4,
    "common/tools/netem_trace.py": 1,
    "common/tools/netns.py": 2,
    "common/tools/setup.py": 8,
    "common/tools/setup_command.py": 9,
    "common/tools/setup_fleet.py": 11,
    "common/tools/trace_command.py": 2,
    "follower/app.py": 6,
    "follower/capacity.py": 1,
    "follower/custody.py": 1,
    "follower/loop.py": 1,
    "follower/sim/gait.py": 2,
    "follower/sim/turn_onset.py": 2,
    "follower/video.py": 1,
    "leader/app.py": 16,
    "leader/blind.py": 1,
    "leader/cockpit/guard.py": 2,
    "leader/cockpit/process.py": 2,
    "leader/config.py": 1,
    "leader/devices/sim_falcon.py": 1,
    "leader/linkquality.py": 3,
    "leader/loop.py": 2,
    "leader/observe.py": 5,
    "leader/operator_check.py": 1,
    "leader/reach.py": 5,
    "leader/videoparts.py": 3,
    "scripts/cockpit_screenshot.py": 2,
    "tests/e2e/adversary_support.py": 4,
    "tests/e2e/cockpit_flood.py": 2,
    "tests/e2e/e2e_support.py": 10,
    "tests/e2e/garbage.py": 2,
    "tests/e2e/test_adversary_cockpit.py": 7,
    "tests/e2e/test_adversary_network.py": 10,
    "tests/e2e/test_adversary_replay.py": 3,
    "tests/e2e/test_adversary_restart.py": 3,
    "tests/e2e/test_adversary_video_replay.py": 1,
    "tests/e2e/test_compose.py": 4,
    "tests/e2e/test_garbage.py": 4,
    "tests/e2e/test_leader_loss.py": 1,
    "tests/e2e/test_leader_reach.py": 1,
    "tests/e2e/test_operator_side.py": 4,
    "tests/e2e/test_router_restart.py": 1,
    "tests/e2e/test_sites_fleet.py": 8,
    "tests/e2e/test_toy_plugin.py": 3,
    "tests/e2e/test_two_continents.py": 5,
    "tests/e2e/test_two_hosts.py": 5,
    "tests/e2e/test_udp_link_heal.py": 4,
    "tests/e2e/test_uplink_gap.py": 1,
    "tests/e2e/udp_spoof.py": 1,
    "tests/e2e/zclient.py": 1,
    "tests/fleet_support.py": 1,
    "tests/integration/leader_stub_follower.py": 1,
    "tests/integration/netns_driver.py": 2,
    "tests/integration/test_cockpit_browser.py": 3,
    "tests/integration/test_fast_mode.py": 2,
    "tests/integration/test_fleet_observer.py": 7,
    "tests/integration/test_fleet_people.py": 2,
    "tests/integration/test_forged_video.py": 2,
    "tests/integration/test_leader_zenoh.py": 7,
    "tests/integration/test_link_failures.py": 4,
    "tests/integration/test_linkemu_namespaces.py": 3,
    "tests/integration/test_netem_namespaces.py": 2,
    "tests/integration/test_obstacle_feel.py": 3,
    "tests/integration/test_record_repair.py": 3,
    "tests/integration/test_relink_loopback.py": 2,
    "tests/integration/test_tbf_fidelity.py": 5,
    "tests/integration/test_trace_replay.py": 4,
    "tests/integration/test_transport.py": 1,
    "tests/integration/test_transport_oversize.py": 2,
    "tests/integration/test_udp_door.py": 3,
    "tests/unit/test_checks.py": 3,
    "tests/unit/test_cli_help.py": 1,
    "tests/unit/test_clock_queueing.py": 1,
    "tests/unit/test_clocklink.py": 1,
    "tests/unit/test_cockpit.py": 5,
    "tests/unit/test_cockpit_guard.py": 1,
    "tests/unit/test_command_reach.py": 1,
    "tests/unit/test_core_dependencies.py": 1,
    "tests/unit/test_demo_cli.py": 2,
    "tests/unit/test_docker.py": 2,
    "tests/unit/test_docs_commands.py": 1,
    "tests/unit/test_docs_site.py": 1,
    "tests/unit/test_follower_capacity.py": 2,
    "tests/unit/test_foxglove_live.py": 1,
    "tests/unit/test_leader_linkquality.py": 2,
    "tests/unit/test_leader_loop.py": 2,
    "tests/unit/test_leader_operators.py": 4,
    "tests/unit/test_nao_guard.py": 1,
    "tests/unit/test_netem.py": 10,
    "tests/unit/test_odometry.py": 3,
    "tests/unit/test_python_versions.py": 5,
    "tests/unit/test_recording.py": 1,
    "tests/unit/test_recording_schemas.py": 12,
    "tests/unit/test_relink.py": 1,
    "tests/unit/test_report.py": 2,
    "tests/unit/test_secrets.py": 3,
    "tests/unit/test_session.py": 3,
    "tests/unit/test_setup.py": 5,
    "tests/unit/test_setup_fleet.py": 16,
    "tests/unit/test_shapers.py": 1,
    "tests/unit/test_sim_robot.py": 1,
    "tests/unit/test_telemetry.py": 2,
    "tests/unit/test_torque_walker.py": 1,
    "tests/unit/test_transport_config.py": 5,
    "tests/unit/test_uplink_gaps.py": 4,
    "tests/unit/test_walker_map.py": 2,
}

_FMT_COMMENT = re.compile(r"\bfmt:\s*(skip|off)\b")


def _functions(node: ast.AST, prefix: str = "") -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    """Every function and method under ``node``, with its qualified name."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
            name = f"{prefix}{child.name}"
            yield name, child
            yield from _functions(child, f"{name}.")
        elif isinstance(child, ast.ClassDef):
            yield from _functions(child, f"{prefix}{child.name}.")
        else:
            yield from _functions(child, prefix)


def _sources(root: Path, parts: tuple[str, ...]) -> Iterator[tuple[str, str]]:
    """Every Python file of ``parts`` under ``root``: path relative to ``root``, text."""
    for part in parts:
        for path in sorted((root / part).rglob("*.py")):
            if "__pycache__" not in path.parts:
                yield path.relative_to(root).as_posix(), path.read_text(encoding="utf-8")


def offenders(root: Path) -> dict[str, int]:
    """Return every module over the bound and every function over it, with its size.

    Parameters
    ----------
    root : Path
        The repository (or a tree laid out like it).

    Returns
    -------
    dict of str to int
        ``path`` or ``path:qualname`` (paths relative to ``root``) -> lines.
    """
    out: dict[str, int] = {}
    for rel, text in _sources(root, PARTS):
        lines = len(text.splitlines())
        if lines > MAX_MODULE_LINES:
            out[rel] = lines
        for name, fn in _functions(ast.parse(text, filename=rel)):
            size = (fn.end_lineno or fn.lineno) - fn.lineno + 1
            if size > MAX_FUNCTION_LINES:
                out[f"{rel}:{name}"] = size
    return out


def fmt_skips(root: Path) -> dict[str, int]:
    """Return the ``# fmt: skip`` (and ``# fmt: off``) comments per file of :data:`FMT_PARTS`.

    Parameters
    ----------
    root : Path
        The repository (or a tree laid out like it).

    Returns
    -------
    dict of str to int
        Path relative to ``root`` -> comments (files with none left out).
    """
    out: dict[str, int] = {}
    for rel, text in _sources(root, FMT_PARTS):
        tokens = tokenize.generate_tokens(io.StringIO(text).readline)
        n = sum(1 for tok in tokens if tok.type == tokenize.COMMENT and _FMT_COMMENT.search(tok.string))
        if n:
            out[rel] = n
    return out


def _allowed_skips() -> dict[str, int]:
    return {**FMT_SKIP_KNOWN, **{k: n for k, (n, _) in FMT_SKIP_TABLES.items()}}


@pytest.mark.timeout(60)
def test_no_module_or_function_is_too_large_beyond_the_known_ones() -> None:
    found = offenders(ROOT)
    print(f"known offenders ({len(KNOWN)}), to be split:")
    for k, why in KNOWN.items():
        print(f"  {k}: {found.get(k, 0)} lines: {why}")
    new = {k: v for k, v in sorted(found.items()) if k not in KNOWN}
    assert not new, (
        f"over {MAX_MODULE_LINES} lines (modules) or {MAX_FUNCTION_LINES} lines (functions); "
        "split them by job:\n" + "\n".join(f"  {k}: {v} lines" for k, v in new.items())
    )


@pytest.mark.timeout(60)
def test_the_known_list_only_shrinks() -> None:
    found = offenders(ROOT)
    gone = sorted(k for k in KNOWN if k not in found)
    assert not gone, "no longer too large: remove from KNOWN:\n" + "\n".join(f"  {k}" for k in gone)


@pytest.mark.timeout(60)
def test_a_planted_module_and_function_are_found(tmp_path: Path) -> None:
    for part in ("common", "leader", "bench"):
        (tmp_path / part).mkdir()
    (tmp_path / "common" / "big.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    (tmp_path / "leader" / "big.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    (tmp_path / "common" / "fits.py").write_text("x = 1\n" * MAX_MODULE_LINES)
    long_body = "    x = 1\n" * MAX_FUNCTION_LINES  # with its def line: one line too many
    fit_body = "    x = 1\n" * (MAX_FUNCTION_LINES - 1)
    method = "        x = 1\n" * MAX_FUNCTION_LINES
    (tmp_path / "bench" / "long.py").write_text(
        f"def f():\n{long_body}\ndef g():\n{fit_body}\nclass A:\n    def m(self):\n{method}"
    )
    assert offenders(tmp_path) == {
        "common/big.py": MAX_MODULE_LINES + 1,
        "leader/big.py": MAX_MODULE_LINES + 1,
        "bench/long.py:f": MAX_FUNCTION_LINES + 1,
        "bench/long.py:A.m": MAX_FUNCTION_LINES + 1,
    }


@pytest.mark.timeout(60)
def test_fmt_skip_only_where_allowed_and_never_more() -> None:
    found, allowed = fmt_skips(ROOT), _allowed_skips()
    print(f"# fmt: skip: {sum(found.values())} lines in {len(found)} files (allowed {sum(allowed.values())})")
    over = {k: (n, allowed.get(k, 0)) for k, n in sorted(found.items()) if n > allowed.get(k, 0)}
    assert not over, (
        "# fmt: skip only where a table needs it (tests/unit/test_sizes.py); let ruff format these lines:\n"
        + "\n".join(f"  {k}: {n} (allowed {a})" for k, (n, a) in over.items())
    )


@pytest.mark.timeout(60)
def test_the_fmt_skip_counts_only_go_down() -> None:
    found, allowed = fmt_skips(ROOT), _allowed_skips()
    stale = {k: (a, found.get(k, 0)) for k, a in sorted(allowed.items()) if found.get(k, 0) < a}
    assert not stale, "fewer # fmt: skip than recorded: lower (or remove) the entry:\n" + "\n".join(
        f'  "{k}": {n},  (was {a})' for k, (a, n) in stale.items()
    )


@pytest.mark.timeout(60)
def test_planted_fmt_skips_are_counted(tmp_path: Path) -> None:
    (tmp_path / "leader").mkdir()
    (tmp_path / "tests").mkdir()
    (tmp_path / "leader" / "a.py").write_text(
        'X = (1, 2)  # fmt: skip\nY = "# fmt: skip"  # a string, not a comment\n# fmt: off\nZ = 3\n# fmt: on\n'
    )
    (tmp_path / "tests" / "b.py").write_text("W = [1]  # noqa: E501 # fmt: skip\n")
    (tmp_path / "leader" / "none.py").write_text("V = 1\n")
    assert fmt_skips(tmp_path) == {"leader/a.py": 2, "tests/b.py": 1}
