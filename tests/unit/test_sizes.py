"""One job per room (issue 22, issue 34 item 5): module and function sizes, and ``# fmt: skip``.

Sizes. The product's folders (``common/``, ``leader/``, ``follower/``, ``studies/``, ``configs/``,
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
of docs/cockpit.md. Every other line is left to the formatter (462 lines in 133 files
were reformatted when the list of old offenders was emptied); a file with one fails. The comments
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
PARTS = ("common", "leader", "follower", "studies", "configs", "docker", "bench")
#: The folders whose formatter-skip comments (:data:`_FMT_COMMENT`) are counted.
FMT_PARTS = (*PARTS, "tests", "scripts", "docs")
#: Longest module of any folder of :data:`PARTS` [lines].
MAX_MODULE_LINES = 600
#: Longest function or method [lines].
MAX_FUNCTION_LINES = 80

#: Offenders not yet split: ``path`` (a module) or ``path:qualname`` (a function) -> why. None
#: since the modules and functions the formatter lengthened were split by job.
KNOWN: dict[str, str] = {}

#: Files whose formatter-skip lines keep a table's rows -> how many, and which table.
FMT_SKIP_TABLES: dict[str, tuple[int, str]] = {
    "leader/cockpit/protocol.py": (1, "SAMPLE_KEYS, the cockpit's telemetry keys one row per group"),
}
#: Every other file with formatter-skip lines when this rule came -> the most it may keep.
FMT_SKIP_KNOWN: dict[str, int] = {}

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
