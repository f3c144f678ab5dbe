"""The README and the docs say only what the code does: every command in a README code block parses with the
real ``prt`` argument parser, every link and repository path resolves, and no issue numbers are left in the text."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from prt_torch.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DOCS = [ROOT / "README.md", ROOT / "docs" / "DESIGN.md", ROOT / "docs" / "RESULTS.md"]


def _code_lines(text: str) -> list[str]:
    """The lines of the ```bash blocks of ``text``, comments stripped, split on ``&&``."""
    lines: list[str] = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.S):
        for line in block.splitlines():
            line = re.sub(r"\s+#.*$", "", line).strip()
            lines.extend(part.strip() for part in line.split("&&") if part.strip())
    return lines


def test_readme_has_code_blocks() -> None:
    """The checks below have something to check: the README's tour is a bash block of ``prt`` commands."""
    lines = _code_lines((ROOT / "README.md").read_text())
    assert sum(line.startswith("prt ") for line in lines) >= 10


def test_readme_commands_parse() -> None:
    """Every ``prt ...`` command of the README's code blocks is accepted by the parser ``prt`` runs (its flags and
    sub-commands exist); every ``bash FILE`` names a script of the repository."""
    bad: list[str] = []
    for line in _code_lines((ROOT / "README.md").read_text()):
        argv = shlex.split(line)
        if argv[0] == "prt":
            try:
                build_parser().parse_args(argv[1:])
            except SystemExit:
                bad.append(line)
        elif argv[0] == "bash":
            if not (ROOT / argv[1]).is_file():
                bad.append(line)
    assert not bad, f"README commands the CLI refuses: {bad}"


def _anchors(page: Path) -> set[str]:
    """The section anchors of a Markdown page as GitHub spells them: the heading in lower case, characters other
    than word characters, hyphens and spaces dropped, spaces turned into hyphens."""
    heads = re.findall(r"^#+ (.+?)\s*$", page.read_text(), flags=re.M)
    return {re.sub(r"[^\w\- ]", "", h.lower()).replace(" ", "-") for h in heads}


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_links_resolve(doc: Path) -> None:
    """Every relative Markdown link or image of the page names a file that exists (relative to the page), and a
    link's ``#section`` a heading of that file."""
    text = doc.read_text()
    targets = [t for t in re.findall(r"\]\(([^)\s]+)\)", text) if not re.match(r"[a-z]+:", t)]
    missing: list[str] = []
    for target in targets:
        path, _, anchor = target.partition("#")
        page = doc.parent / path if path else doc
        if not page.exists() or (anchor and anchor not in _anchors(page)):
            missing.append(target)
    assert not missing, f"{doc.name}: links to missing files or sections {missing}"


def test_readme_paths_exist() -> None:
    """Repository paths the README names in backticks or commands (configs, docs, scripts, web sources) exist;
    ``../shared/data`` paths exist where the shared data is present."""
    text = (ROOT / "README.md").read_text()
    paths = set(re.findall(r"(?<![\w./-])((?:configs|docs|scripts|web/src|tests)/[\w./-]*\w)", text))
    assert paths, "no repository paths found in the README"
    missing = sorted(p for p in paths if not (ROOT / p).exists())
    assert not missing, f"README names missing paths {missing}"
    shared = set(re.findall(r"\.\./shared/data/[\w./-]*\w", text))
    if SHARED.is_dir():
        gone = sorted(p for p in shared if not (ROOT / p).exists())
        assert not gone, f"README names missing shared data {gone}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_no_issue_numbers(doc: Path) -> None:
    """The docs state facts, not the project's history: no "issue NN" references."""
    hits = re.findall(r".{0,30}\bissues? \d+.{0,30}", doc.read_text(), flags=re.I)
    assert not hits, f"{doc.name}: issue numbers in the text: {hits}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_no_empty_sections(doc: Path) -> None:
    """No heading is followed directly by another of the same or a higher level (a section without a body: a
    section inserted between a heading and its text)."""
    text = re.sub(r"```.*?```", "code", doc.read_text(), flags=re.S)  # a body; its '#' lines are comments
    lines = [line for line in text.splitlines() if line.strip()]
    empty = [a for a, b in zip(lines, lines[1:], strict=False)
             if (m := re.match(r"(#+) ", a)) and (n := re.match(r"(#+) ", b)) and len(n.group(1)) <= len(m.group(1))]
    assert not empty, f"{doc.name}: sections without a body: {empty}"
