"""One job per room (issue 22): no module of ``common/`` over 600 lines, no function over 80.

The product's folders (``common/``, ``leader/``, ``follower/``, ``configs/``, ``docker/``,
``bench/``; tests are not measured) are read with :mod:`ast`. A function's size is
``end_lineno - lineno + 1`` (its ``def`` line to its last line, decorators not counted);
methods and nested functions count on their own, named ``Class.method`` or
``outer.inner``. :data:`KNOWN` would list an offender allowed for now (it is empty); a new
offender fails, and so does an entry of :data:`KNOWN` that is no longer one.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: The folders measured (the package's and the programs' around it).
PARTS = ("common", "leader", "follower", "configs", "docker", "bench")
#: Longest module of ``common/`` [lines].
MAX_MODULE_LINES = 600
#: Longest function or method [lines].
MAX_FUNCTION_LINES = 80

#: Offenders not yet split: ``path`` (a module of ``common/``) or ``path:qualname`` (a function).
#: Empty since issue 22's last splits (config, the benches' mains, the gait's step plan, the URDF).
KNOWN: dict[str, str] = {}


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


def offenders(root: Path) -> dict[str, int]:
    """Return every module of ``common/`` over the bound and every function over it, with its size.

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
    for part in PARTS:
        for path in sorted((root / part).rglob("*.py")):
            rel = path.relative_to(root).as_posix()
            text = path.read_text(encoding="utf-8")
            lines = len(text.splitlines())
            if part == "common" and lines > MAX_MODULE_LINES:
                out[rel] = lines
            for name, fn in _functions(ast.parse(text, filename=rel)):
                size = (fn.end_lineno or fn.lineno) - fn.lineno + 1
                if size > MAX_FUNCTION_LINES:
                    out[f"{rel}:{name}"] = size
    return out


@pytest.mark.timeout(60)
def test_no_module_or_function_is_too_large_beyond_the_known_ones() -> None:
    found = offenders(ROOT)
    new = {k: v for k, v in sorted(found.items()) if k not in KNOWN}
    assert not new, (
        f"over {MAX_MODULE_LINES} lines (modules of common/) or {MAX_FUNCTION_LINES} lines (functions); "
        "split them by job:\n" + "\n".join(f"  {k}: {v} lines" for k, v in new.items())
    )


@pytest.mark.timeout(60)
def test_the_known_list_only_shrinks() -> None:
    found = offenders(ROOT)
    gone = sorted(k for k in KNOWN if k not in found)
    assert not gone, "no longer too large: remove from KNOWN:\n" + "\n".join(f"  {k}" for k in gone)


@pytest.mark.timeout(60)
def test_a_planted_module_and_function_are_found(tmp_path: Path) -> None:
    (tmp_path / "common").mkdir()
    (tmp_path / "bench").mkdir()
    (tmp_path / "common" / "big.py").write_text("x = 1\n" * (MAX_MODULE_LINES + 1))
    (tmp_path / "common" / "fits.py").write_text("x = 1\n" * MAX_MODULE_LINES)
    long_body = "    x = 1\n" * MAX_FUNCTION_LINES  # with its def line: one line too many
    fit_body = "    x = 1\n" * (MAX_FUNCTION_LINES - 1)
    method = "        x = 1\n" * MAX_FUNCTION_LINES
    (tmp_path / "bench" / "long.py").write_text(
        f"def f():\n{long_body}\ndef g():\n{fit_body}\nclass A:\n    def m(self):\n{method}"
    )
    assert offenders(tmp_path) == {
        "common/big.py": MAX_MODULE_LINES + 1,
        "bench/long.py:f": MAX_FUNCTION_LINES + 1,
        "bench/long.py:A.m": MAX_FUNCTION_LINES + 1,
    }
