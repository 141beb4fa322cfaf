"""Every link between the manual's pages reaches a file, and its #anchor a heading of that page
(the results pages move and condense; a link left behind would point nowhere)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: a markdown link (not an image): its target, up to whitespace or the closing parenthesis
LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"```.*?```", re.S)


def heading_anchors(markdown: str) -> set[str]:
    """The anchors GitHub gives a page's headings: lower case, punctuation out, spaces to
    hyphens, a repeated heading suffixed -1, -2, ..."""
    seen: dict[str, int] = {}
    anchors = set()
    for line in FENCE.sub("", markdown).splitlines():
        m = re.match(r"#{1,6}\s+(.*)", line)
        if not m:
            continue
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().replace("`", "").lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        anchors.add(slug if n == 0 else f"{slug}-{n}")
    return anchors


def test_heading_anchors_follow_githubs_rule():
    page = "# Title\n## `opv2v`: for OpenCOOD\n```\n# not a heading\n```\n## Title\n### Table I, at 219 scenes\n"
    assert heading_anchors(page) == {"title", "opv2v-for-opencood", "title-1", "table-i-at-219-scenes"}


def broken_links(pages: list[Path], root: Path = ROOT) -> list[str]:
    broken = []
    for page in pages:
        for target in LINK.findall(FENCE.sub("", page.read_text(encoding="utf-8"))):
            if re.match(r"[a-z]+:", target):  # https:, mailto:
                continue
            path, _, anchor = target.partition("#")
            linked = (page.parent / path).resolve() if path else page
            where = f"{page.relative_to(root)}: ({target})"
            if not linked.exists():
                broken.append(f"{where} no such file")
            elif anchor and linked.suffix == ".md" and anchor not in heading_anchors(linked.read_text(encoding="utf-8")):
                broken.append(f"{where} no such heading")
    return broken


def test_a_broken_link_is_found(tmp_path):
    (tmp_path / "a.md").write_text("# A\n[ok](b.md#b) [gone](c.md) [wrong](b.md#nothing) [web](https://x.org)\n")
    (tmp_path / "b.md").write_text("# B\n")
    assert broken_links([tmp_path / "a.md"], tmp_path) == ["a.md: (c.md) no such file", "a.md: (b.md#nothing) no such heading"]


def test_every_link_of_the_manual_reaches_its_page_and_heading():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    assert not broken_links(pages), "\n".join(broken_links(pages))
