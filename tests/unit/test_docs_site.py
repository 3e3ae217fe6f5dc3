"""The documentation site and the front page: built for real, strict, and kept honest.

The site (``mkdocs.yml``) builds in strict mode; a planted broken link, a planted broken
anchor and a page left out of the navigation each fail the build; the generated CLI
reference names every sub-command and every option; the README stays a front door; no
user-facing page carries issue numbers or work history; the changelog's newest version is
the package's.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import bipedtele
import pytest

pytestmark = [pytest.mark.slow, pytest.mark.compute, pytest.mark.timeout(400)]

ROOT = Path(__file__).resolve().parents[2]
MKDOCS = [sys.executable, "-m", "mkdocs"]
#: Pages another part of the project owns and cleans (the method's working notes).
HISTORY_EXEMPT = {"method.md"}


def _hooks() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bipedtele_docs_hooks", ROOT / "docs" / "hooks" / "bipedtele_docs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _build(project: Path, site: Path) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run(
        [*MKDOCS, "build", "--strict", "--site-dir", str(site)],
        cwd=project,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("site")
    proc = _build(ROOT, out)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    return out


def test_the_site_builds_strict_with_every_page(site: Path) -> None:
    for page in ("index.html", "cli/index.html", "api/robots/index.html", "results/index.html", "changelog/index.html"):
        assert (site / page).is_file(), page
    assert (site / "search" / "search_index.json").is_file()
    # the changelog is included from the repository's CHANGELOG.md
    assert f"[{bipedtele.__version__}]" in (site / "changelog" / "index.html").read_text()


def test_planted_broken_link_anchor_and_orphan_page_fail_the_build(tmp_path: Path) -> None:
    project = tmp_path / "project"
    project.mkdir()
    shutil.copy(ROOT / "mkdocs.yml", project / "mkdocs.yml")
    shutil.copy(ROOT / "CHANGELOG.md", project / "CHANGELOG.md")
    shutil.copytree(ROOT / "docs", project / "docs", ignore=shutil.ignore_patterns("__pycache__"))
    for folder in ("common", "leader", "follower", "studies", "configs"):  # the API pages' sources (2 MB)
        shutil.copytree(ROOT / folder, project / folder, ignore=shutil.ignore_patterns("__pycache__"))
    # the unchanged copy builds: what fails below is what was planted
    assert _build(project, tmp_path / "clean").returncode == 0
    index = project / "docs" / "index.md"
    index.write_text(
        index.read_text() + "\n[planted page](no-such-page.md) and [planted anchor](results.md#no-such-anchor)\n"
    )
    (project / "docs" / "orphan-planted.md").write_text("# Not in the navigation\n")
    proc = _build(project, tmp_path / "broken")
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out[-3000:]
    assert "no-such-page.md" in out, out[-3000:]
    assert "#no-such-anchor" in out, out[-3000:]
    assert "orphan-planted.md" in out, out[-3000:]
    assert "Aborted with 3 warnings in strict mode" in out, out[-3000:]


def test_the_cli_reference_lists_every_sub_command_with_its_options(site: Path) -> None:
    html = (site / "cli" / "index.html").read_text()
    commands = _hooks().command_parsers()
    names = {name for name, _, _ in commands}
    from importlib import metadata

    assert names == {ep.name for ep in metadata.entry_points(group="bipedtele.commands")}

    def check(parser: argparse.ArgumentParser, title: str) -> None:
        anchor = "bipedtele-" + title.replace(" ", "-")
        assert f'id="{anchor}"' in html, anchor
        section = html[html.index(f'id="{anchor}"') :]
        for action in parser._actions:
            if action.help is argparse.SUPPRESS:
                continue
            for option in action.option_strings:
                assert f"<code>{option}</code>" in section, (title, option)
            if isinstance(action, argparse._SubParsersAction):
                for sub_name, sub_parser in action.choices.items():
                    check(sub_parser, f"{title} {sub_name}")

    for name, _, parser in commands:
        check(parser, name)


def _fenced_blocks(text: str) -> list[str]:
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.S | re.M)


def test_the_readme_is_a_front_door() -> None:
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) < 200, len(text.splitlines())
    blocks = _fenced_blocks(text)
    assert blocks[0].strip() == "scripts/bootstrap.sh && .venv/bin/bipedtele demo"
    assert blocks[1].strip() == "bash scripts/test.sh"
    assert "docs/cockpit.png" in text
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if not re.match(r"[a-z]+://", target):
            assert (ROOT / target).exists(), target


def test_no_issue_numbers_or_work_history_in_user_pages() -> None:
    pattern = re.compile(r"issue [0-9]|this session|this wave")
    pages = [ROOT / "README.md", ROOT / "CHANGELOG.md"]
    pages += [p for p in (ROOT / "docs").rglob("*.md") if p.name not in HISTORY_EXEMPT]
    hits = [
        f"{page.relative_to(ROOT)}:{n}: {line.strip()}"
        for page in pages
        for n, line in enumerate(page.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert not hits, "\n".join(hits)


def test_the_changelog_starts_at_the_package_version() -> None:
    text = (ROOT / "CHANGELOG.md").read_text()
    versions = re.findall(r"^## \[([^\]]+)\]", text, flags=re.M)
    released = [v for v in versions if v != "Unreleased"]
    assert released, "no version in CHANGELOG.md"
    assert released[0] == bipedtele.__version__, (released[0], bipedtele.__version__)
    assert released[-1] == "0.1.0"
    out = subprocess.run(
        [sys.executable, "-m", "bipedtele.cli", "--version"], capture_output=True, text=True, timeout=60, check=True
    ).stdout
    assert out.strip() == f"bipedtele {released[0]}"
