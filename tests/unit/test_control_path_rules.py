"""Rules of the control path, read from the source (ast): no deepcopy, no switch on a scheme.

* **No deepcopy in a control path.** The modules that run the controller steps (the control
  laws in ``common/control``, the real loops, the comparison's runner and the studies' loops)
  re-run a period by keeping the step's state value from before it, never by deep-copying
  models (docs/architecture.md, "Controller steps").
* **No scheme switch outside the scheme modules.** A scheme's laws are its class's methods
  (``common/control/schemes``); nowhere else asks which scheme it is: no comparison of a
  ``scheme`` setting or a scheme's ``name`` against a registered scheme's name, no
  ``isinstance`` against a scheme class, in any product module.
* **A loop is built in one call.** ``FollowerLoop`` and ``LeaderLoop`` take everything in
  their constructor: no product module outside the loop's own sets an attribute of a loop
  after it is built (``loop.x = ...``, ``self.loop.x = ...``, ``self._loop.x = ...``).
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import TypeGuard

import pytest
from bipedtele.control.schemes import Scheme, scheme_class, scheme_names

ROOT = Path(__file__).resolve().parents[2]
PRODUCT = ("common", "leader", "follower", "studies")
SCHEME_MODULES = ROOT / "common" / "control" / "schemes"
#: The modules that run a controller step, or hold its laws.
CONTROL_PATH = (
    *sorted((ROOT / "common" / "control").rglob("*.py")),
    ROOT / "follower" / "loop.py",
    ROOT / "follower" / "walkstate.py",
    ROOT / "leader" / "loop.py",
    ROOT / "studies" / "compare_kernel.py",
    ROOT / "studies" / "study.py",
    ROOT / "studies" / "walker_study.py",
)


def _product_modules() -> list[Path]:
    return sorted(p for d in PRODUCT for p in (ROOT / d).rglob("*.py") if ".venv" not in p.parts)


def deepcopies(tree: ast.AST) -> list[int]:
    """Return the lines that deep-copy: ``copy.deepcopy(...)``, ``deepcopy(...)`` or importing it."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            f = node.func
            if (isinstance(f, ast.Attribute) and f.attr == "deepcopy") or (
                isinstance(f, ast.Name) and f.id == "deepcopy"
            ):
                lines.append(node.lineno)
        elif (
            isinstance(node, ast.ImportFrom) and node.module == "copy" and any(a.name == "deepcopy" for a in node.names)
        ):
            lines.append(node.lineno)
    return lines


def _names_scheme(node: ast.expr) -> bool:
    """Whether ``node`` reads a scheme setting or a scheme's name (``cfg.scheme``, ``scheme.name``, ``scheme``)."""
    if isinstance(node, ast.Attribute):
        if node.attr == "scheme":
            return True
        if node.attr in ("name", "feedback", "kind"):
            return _names_scheme(node.value) or (isinstance(node.value, ast.Name) and "scheme" in node.value.id)
    return isinstance(node, ast.Name) and node.id in ("scheme", "scheme_name")


def _constants(node: ast.expr) -> set[str]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return {node.value}
    if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
        return {e.value for e in node.elts if isinstance(e, ast.Constant) and isinstance(e.value, str)}
    return set()


def _is_isinstance(node: ast.AST) -> TypeGuard[ast.Call]:
    return (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id == "isinstance"
        and len(node.args) == 2
    )


def scheme_switches(tree: ast.AST, names: set[str], classes: set[str]) -> list[int]:
    """Return the lines that switch on a scheme: a scheme setting or name compared with a scheme's name, or an isinstance on a scheme class."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            operands = [node.left, *node.comparators]
            if any(_names_scheme(o) for o in operands) and any(_constants(o) & names for o in operands):
                lines.append(node.lineno)
        elif _is_isinstance(node):
            target = node.args[1]
            found = {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
            found |= {n.attr for n in ast.walk(target) if isinstance(n, ast.Attribute)}
            if found & classes:
                lines.append(node.lineno)
    return lines


LOOP_MODULES = (ROOT / "follower" / "loop.py", ROOT / "leader" / "loop.py")


def _is_loop(node: ast.expr) -> bool:
    """Whether ``node`` names a loop object: ``loop``, ``*_loop``, or an attribute so named."""
    name = node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else ""
    return name == "loop" or name.endswith("_loop")


def loop_attribute_sets(tree: ast.AST) -> list[int]:
    """Return the lines that set an attribute of a loop object (``loop.x = ...``, augmented too)."""
    lines = []
    for node in ast.walk(tree):
        targets: list[ast.expr] = []
        if isinstance(node, ast.Assign):
            targets = list(node.targets)
        elif isinstance(node, (ast.AugAssign, ast.AnnAssign)):
            targets = [node.target]
        flat = [e for t in targets for e in (t.elts if isinstance(t, ast.Tuple) else [t])]
        if any(isinstance(t, ast.Attribute) and _is_loop(t.value) for t in flat):
            lines.append(node.lineno)
    return lines


def _scheme_vocabulary() -> tuple[set[str], set[str]]:
    names = set(scheme_names())
    classes: set[str] = set()
    todo = [scheme_class(n) for n in names]
    while todo:  # every class a scheme is built from, its mixins included
        cls = todo.pop()
        for c in cls.__mro__:
            if isinstance(c, type) and issubclass(c, Scheme) and c is not Scheme and c.__name__ not in classes:
                classes.add(c.__name__)
    return names, classes


@pytest.mark.timeout(60)
def test_no_deepcopy_in_a_control_path() -> None:
    found = {str(p.relative_to(ROOT)): lines for p in CONTROL_PATH if (lines := deepcopies(ast.parse(p.read_text())))}
    assert found == {}


@pytest.mark.timeout(60)
def test_no_scheme_switch_outside_the_scheme_modules() -> None:
    names, classes = _scheme_vocabulary()
    assert {"paper", "wave", "tdpa"} <= names and {"Wave", "Passivity"} <= classes
    found = {}
    for p in _product_modules():
        if SCHEME_MODULES in p.parents:
            continue
        lines = scheme_switches(ast.parse(p.read_text()), names, classes)
        if lines:
            found[str(p.relative_to(ROOT))] = lines
    assert found == {}


@pytest.mark.timeout(60)
def test_nothing_is_set_on_a_loop_after_it_is_built() -> None:
    found = {}
    for p in _product_modules():
        if p in LOOP_MODULES:
            continue
        lines = loop_attribute_sets(ast.parse(p.read_text()))
        if lines:
            found[str(p.relative_to(ROOT))] = lines
    assert found == {}


@pytest.mark.timeout(60)
def test_the_rules_see_what_they_forbid() -> None:
    names, classes = _scheme_vocabulary()
    src = """
import copy
from copy import deepcopy
a = copy.deepcopy(b)
if cfg.scheme == "wave": pass
if self.scheme.name in ("paper", "tdpa"): pass
if isinstance(s, Wave): pass
if scheme.feedback == "paper": pass
ok = parts.scheme in ("http", "https")
ok = self.hybrid_model in ("paper", "walker")
ok = cfg.scheme not in scheme_names()
"""
    tree = ast.parse(src)
    assert deepcopies(tree) == [3, 4]
    assert scheme_switches(tree, names, classes) == [5, 6, 7, 8]
    sets = """
loop = FollowerLoop(cfg)
loop.robot = robot
self.loop.on_event = f
self._loop.n += 1
a.b, self.leader_loop.c = 1, 2
ok = loop
ok.loop = loop
"""
    assert loop_attribute_sets(ast.parse(sets)) == [3, 4, 5, 6]
