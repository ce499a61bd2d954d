"""The README is a path and the docs hold together: every relative markdown link in README.md,
docs/*.md and export/CONTRACT.md names a file that exists (and, into a markdown file, a heading
it has), every docs file is in the docs index, and the README keeps its two set-up commands
(real Makefile targets) and its where-next table near the top."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md"))
PAGES = [ROOT / "README.md", *DOCS, ROOT / "export" / "CONTRACT.md"]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~)")


def _prose(text: str) -> list[str]:
    """The lines outside fenced code blocks, inline code spans removed."""
    lines, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(re.sub(r"`[^`]*`", "", line))
    return lines


def _anchors(path: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens, -N repeats."""
    seen: dict[str, int] = {}
    out = set()
    fenced = False
    for line in path.read_text().splitlines():
        if FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if fenced or not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


def _links(page: Path) -> list[str]:
    return [t for line in _prose(page.read_text()) for t in LINK.findall(line)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_links_are_whole(page: Path) -> None:
    """Every ``](`` opens a link that closes on its line (a cut link is found, not skipped)."""
    cut = [ln for ln in _prose(page.read_text()) if ln.count("](") != len(LINK.findall(ln))]
    assert not cut, f"{page.relative_to(ROOT)}: unclosed links in {cut}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(page: Path) -> None:
    bad = []
    for target in _links(page):
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
            continue
        name, _, anchor = target.partition("#")
        dest = (page.parent / name).resolve() if name else page
        if not dest.exists():
            bad.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
            bad.append(f"{target}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    assert not bad, f"{page.relative_to(ROOT)}: " + "; ".join(bad)


def test_anchor_rule() -> None:
    """The slug rule reproduces anchors GitHub is known to make."""
    heading = ROOT / "docs" / "ablation.md"
    assert "sweeps-across-machines---backend-ray" in _anchors(heading)


def test_docs_index_lists_every_docs_file() -> None:
    listed = {t.partition("#")[0] for t in _links(ROOT / "docs" / "README.md")}
    missing = [p.name for p in DOCS if p.name != "README.md" and p.name not in listed]
    assert not missing, f"docs/README.md does not list {missing}"


def test_readme_is_a_path() -> None:
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; measurements belong in docs/"
    first_block = lines[lines.index("```bash") + 1 : lines.index("```")]
    commands = [line.split("#")[0].strip() for line in first_block]
    assert commands == ["make demo", "make test"], first_block
    makefile = (ROOT / "Makefile").read_text()
    for target in ("demo", "test"):
        assert re.search(rf"^{target}:", makefile, re.M), f"Makefile has no {target} target"
    where = next(i for i, line in enumerate(lines) if line.startswith("## Where next"))
    assert where < 60, f"the where-next table starts at line {where + 1}"
    table = [line for line in lines[where:] if line.startswith("|")][:20]
    assert sum("docs/" in line for line in table) >= 10, "the where-next table lost its rows"


def test_readme_layout_is_current() -> None:
    """Every path the Layout section starts a line with exists, and every package is named."""
    text = (ROOT / "README.md").read_text()
    block = text.split("## Layout", 1)[1].split("```", 2)[1]
    named = [line.split("  ")[0].strip() for line in block.splitlines() if line[:1].strip()]
    missing = []
    for entry in named:
        first, *rest = [part.strip() for part in entry.split(",")]
        folder = Path(first).parent
        for name in [first, *(str(folder / r) for r in rest)]:
            if not (ROOT / name).exists():
                missing.append(name)
    assert not missing, f"README Layout names paths that do not exist: {missing}"
    packages = {p.parent.name for p in (ROOT / "slimseg").glob("*/__init__.py")}
    listed = {Path(e.split(",")[0]).name.rstrip("/") for e in named if e.startswith("slimseg/")}
    assert packages <= listed, f"README Layout misses {sorted(packages - listed)}"


def test_readme_commands_parse() -> None:
    """Each `slimseg ...` line of the README's shell blocks is accepted by the real parser."""
    from slimseg.cli.main import build_parser

    text = (ROOT / "README.md").read_text()
    lines = [ln for b in re.findall(r"```bash\n(.*?)```", text, re.S) for ln in b.splitlines()]
    commands = [ln.split(" #")[0].strip() for ln in lines if ln.startswith("slimseg ")]
    assert len(commands) >= 10, commands
    for line in commands:
        line = re.sub(r"\[(--[\w-]+)\]", r"\1", line).replace("$S", "data/seq/sequences/seq_000")
        argv = shlex.split(line)[1:]
        try:
            build_parser(argv).parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"README command does not parse (exit {exc.code}): {line}")


def test_readme_python_names_exist() -> None:
    """The README's Python blocks compile and every ``slimseg.<name>`` they use exists."""
    import ast

    import slimseg

    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)
    assert blocks
    for block in blocks:
        tree = ast.parse(block)
        for node in ast.walk(tree):
            name = node.value if isinstance(node, ast.Attribute) else None
            if isinstance(name, ast.Name) and name.id == "slimseg":
                assert hasattr(slimseg, node.attr), f"slimseg.{node.attr} (README) is gone"
