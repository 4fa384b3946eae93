"""The documentation's relative links resolve: every link and image of README.md and docs/**/*.md names a file or
folder of the repository, an anchor into a Markdown page names one of its headings, and no page points outside the
repository. docs/README.md, the map, lists every page of docs/."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def links(text: str) -> list[tuple[int, str]]:
    """(line number, target) of every Markdown link outside code blocks and code spans."""
    found, fenced = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            found += [(number, m[1]) for m in LINK.finditer(re.sub(r"`[^`]*`", "``", line))]
    return found


def anchors(page: Path) -> set[str]:
    """The anchors GitHub gives the headings of ``page``: lower case, punctuation dropped, spaces as hyphens."""
    found, fenced = set(), False
    for line in page.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
        elif not fenced and (m := re.match(r"#+\s+(.*)", line)):
            found.add(re.sub(r"[^\w\- ]", "", m[1].strip().lower()).replace(" ", "-"))
    return found


def test_the_link_finder_skips_code_and_finds_images():
    assert anchors(ROOT / "README.md") >= {"quickstart-python", "results-at-a-glance", "set-up"}
    text = "[a](x.md) ![b](y.png#k)\n`[c](z.md)`\n```\n[d](w.md)\n```\n[e](https://example.com) [f](#top)"
    assert [t for _, t in links(text)] == ["x.md", "y.png#k", "https://example.com", "#top"]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_names_an_existing_file(page):
    broken = []
    for number, target in links(page.read_text(encoding="utf-8")):
        if re.match(r"[a-z][a-z0-9+.-]*:", target):
            continue  # a URL
        name, _, anchor = target.partition("#")
        path = (page.parent / name).resolve()
        if not path.exists() or ROOT not in (path, *path.parents):
            broken.append(f"{page.relative_to(ROOT)}:{number}: {target}")
        elif anchor and path.suffix == ".md" and anchor not in anchors(path):
            broken.append(f"{page.relative_to(ROOT)}:{number}: {target} (no such heading)")
    assert not broken, "\n".join(broken)


SIBLING_FOLDER = "/".join(("..", "shared"))  # the developers' folder beside a checkout, which a user's clone lacks


def test_no_page_points_outside_the_repository():
    assert not [str(p.relative_to(ROOT)) for p in PAGES if SIBLING_FOLDER in p.read_text(encoding="utf-8")]


def test_the_docs_map_lists_every_page():
    """docs/README.md links every page of docs/."""
    index = ROOT / "docs" / "README.md"
    listed = {(index.parent / t.split("#", 1)[0]).resolve() for _, t in links(index.read_text(encoding="utf-8"))}
    missing = [str(p.relative_to(ROOT)) for p in PAGES[1:] if p != index and p.resolve() not in listed]
    assert not missing, f"docs/README.md does not list {missing}"


def test_the_controller_guide_shows_the_upstream_table_as_its_command_wrote_it():
    table = (ROOT / "benchmarks/results/upstream-roads/table.md").read_text().strip()
    assert table in (ROOT / "docs/controller.md").read_text()
