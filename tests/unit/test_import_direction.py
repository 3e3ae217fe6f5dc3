"""Dependencies point to the core, and no role loads the other's modules.

Each check imports every module of one part in a fresh interpreter and reads
``sys.modules``: the core library (``bipedtele`` without ``tools``/``leader``/``follower``)
must load neither role nor the tools; the tools (``bipedtele.tools``) reach the roles only
through entry points, so they load neither either; every module of the follower must not
load the leader, and the reverse.
The sub-commands each role registers run the same way (``bipedtele follower``,
``bipedtele leader``), so this is also what those programs import.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = r"""
import importlib, json, pkgutil, sys
root, skip = sys.argv[1], sys.argv[2:]
names = [root]
def walk(path, prefix):
    # pkgutil.walk_packages would import the skipped packages to look inside them.
    for info in pkgutil.iter_modules(path, prefix):
        if any(info.name == s or info.name.startswith(s + ".") for s in skip):
            continue
        names.append(info.name)
        mod = importlib.import_module(info.name)
        if info.ispkg:
            walk(mod.__path__, info.name + ".")
walk(importlib.import_module(root).__path__, root + ".")
print(json.dumps({"imported": names, "loaded": sorted(m for m in sys.modules if m.startswith("bipedtele"))}))
"""


def _probe(root: str, *skip: str) -> dict[str, list[str]]:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, root, *skip], capture_output=True, text=True, timeout=240, check=False
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _under(modules: list[str], pkg: str) -> list[str]:
    return [m for m in modules if m == pkg or m.startswith(pkg + ".")]


@pytest.mark.timeout(300)
def test_the_core_imports_neither_role_nor_the_tools() -> None:
    got = _probe("bipedtele", "bipedtele.tools", "bipedtele.leader", "bipedtele.follower", "bipedtele.studies")
    assert len(got["imported"]) > 20  # the whole core was walked
    assert "bipedtele.control.reduced" in got["imported"]
    assert _under(got["imported"], "bipedtele.tools") == []
    assert _under(got["loaded"], "bipedtele.studies") == []
    assert _under(got["loaded"], "bipedtele.leader") == []
    assert _under(got["loaded"], "bipedtele.follower") == []
    assert _under(got["loaded"], "bipedtele.tools") == []
    # The command-line tools live in bipedtele.tools, not beside the library.
    for tool in ("demo", "demostatus", "report", "delayproxy", "netem", "router", "health", "setup", "commands"):
        assert f"bipedtele.{tool}" not in got["imported"], tool


@pytest.mark.timeout(300)
def test_control_is_pure() -> None:
    got = _probe("bipedtele.control")
    assert "bipedtele.control.reduced" in got["imported"]
    assert "bipedtele.control.commands" not in got["imported"]  # no sub-commands in control
    assert "bipedtele.cli" not in got["loaded"]  # no argument parsing


@pytest.mark.timeout(300)
def test_the_tools_import_neither_role() -> None:
    got = _probe("bipedtele.tools")
    assert "bipedtele.tools.demo" in got["imported"]
    assert _under(got["loaded"], "bipedtele.leader") == []
    assert _under(got["loaded"], "bipedtele.follower") == []


@pytest.mark.timeout(300)
def test_the_studies_may_drive_the_simulated_robot_but_never_load_the_leader() -> None:
    got = _probe("bipedtele.studies")
    assert "bipedtele.studies.walker_compare" in got["imported"]
    assert "bipedtele.follower.sim.robot" in got["loaded"]  # the walker cells drive the simulated NAO
    assert _under(got["loaded"], "bipedtele.leader") == []


@pytest.mark.timeout(300)
def test_the_follower_never_loads_the_leader() -> None:
    got = _probe("bipedtele.follower")
    assert "bipedtele.follower.app" in got["imported"]
    assert _under(got["loaded"], "bipedtele.leader") == []


@pytest.mark.timeout(300)
def test_the_leader_never_loads_the_follower() -> None:
    got = _probe("bipedtele.leader")
    assert "bipedtele.leader.app" in got["imported"]
    assert _under(got["loaded"], "bipedtele.follower") == []


def _module_imports(repo: Path, *, deep: bool = False) -> dict[str, set[str]]:
    """Module -> the bipedtele modules it imports (module level, not TYPE_CHECKING; ``deep``: in functions too)."""
    roots = {
        "common": "bipedtele",
        "leader": "bipedtele.leader",
        "follower": "bipedtele.follower",
        "studies": "bipedtele.studies",
    }
    files: dict[str, Path] = {}
    for folder, pkg in roots.items():
        for path in (repo / folder).rglob("*.py"):
            rel = path.relative_to(repo / folder).with_suffix("").parts
            name = ".".join((pkg, *rel[:-1])) if rel[-1] == "__init__" else ".".join((pkg, *rel))
            files[name] = path
    known = set(files)

    def closest(name: str) -> str | None:
        while name and name not in known:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        deps: set[str] = set()
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree) if deep else tree.body:
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
                continue
            targets: list[str] = []
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    base = ".".join(
                        [*package.split(".")[: len(package.split(".")) - node.level + 1], *([base] if base else [])]
                    )
                targets = [f"{base}.{a.name}" for a in node.names] + [base]
            for t in targets:
                hit = closest(t)
                while hit and hit.startswith("bipedtele"):
                    deps.add(hit)  # importing a.b.c runs a and a.b first
                    hit = closest(hit.rpartition(".")[0])
        deps.discard(name)
        graph[name] = {d for d in deps if not name.startswith(d + ".")}  # a module's own parents are loading it
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


@pytest.mark.timeout(60)
def test_no_import_circle() -> None:
    """Issue 22: ``config -> sections -> control.config -> config`` was a circle, hidden by an
    import inside a function. No module-level circle anywhere; in the core none at all,
    imports inside functions included (the roles' lazy imports of their drivers are theirs)."""
    repo = Path(__file__).resolve().parents[2]
    graph = _module_imports(repo)
    assert len(graph) > 100
    assert _cycles(graph) == []
    deep = _module_imports(repo, deep=True)
    core = {m: {d for d in deps if not d.startswith(_ROLES)} for m, deps in deep.items() if not m.startswith(_ROLES)}
    assert "bipedtele.config.sections" in core["bipedtele.config.profile"]
    assert _cycles(core) == []


_ROLES = ("bipedtele.leader", "bipedtele.follower")


def test_the_circle_check_finds_a_circle() -> None:
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []
