"""The documentation's relative links resolve: every Markdown link of README.md and docs/*.md that
is not a URL points to an existing file, and its #anchor, if any, to a heading of that page.

Anchors follow GitHub's rule (the one a reader of the repository sees): the heading lowercased,
characters other than letters, digits, '_', '-' and spaces dropped, spaces made '-', and a repeated
heading suffixed -1, -2, ...
"""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md"] + sorted((ROOT / "docs").glob("*.md"))

LINK = re.compile(r"(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^\s*(```|~~~)")


def prose_lines(text):
    """The lines outside fenced and indented code blocks, with inline code removed."""
    fenced = False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if fenced or line.startswith("    ") or line.startswith("\t"):
            continue
        yield re.sub(r"`[^`]*`", "", line)


def slug(heading):
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def heading_lines(path):
    """Headings with their inline code kept (GitHub keeps code spans' text in anchors)."""
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced and re.match(r"^#{1,6}\s", line):
            yield line


def anchor_set(path):
    seen, out = {}, set()
    for line in heading_lines(path):
        text = re.sub(r"^#{1,6}\s+", "", line).rstrip("# ").replace("`", "")
        s = slug(text)
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def broken_links(page):
    """[(target, reason)] for every relative link of one Markdown page that does not resolve."""
    bad = []
    for line in prose_lines(page.read_text(encoding="utf-8")):
        for m in LINK.finditer(line):
            target = m.group(1) or m.group(2)
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):       # http:, https:, mailto:
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                bad.append((target, "no such file"))
            elif anchor and dest.suffix == ".md" and anchor not in anchor_set(dest):
                bad.append((target, "no such heading"))
    return bad


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    assert broken_links(page) == []


def test_every_docs_page_is_reached_from_the_readme_or_another_page():
    linked = set()
    for page in PAGES:
        for line in prose_lines(page.read_text(encoding="utf-8")):
            for m in LINK.finditer(line):
                target = (m.group(1) or m.group(2)).partition("#")[0]
                if target and not re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):
                    linked.add((page.parent / target).resolve())
    orphans = [p.name for p in PAGES[1:] if p.resolve() not in linked]
    assert orphans == []


def test_the_checker_finds_a_broken_file_link_and_a_broken_anchor(tmp_path):
    """The checker itself: a page with a good link, a missing file, a missing heading, and links
    in code that must be ignored."""
    (tmp_path / "other.md").write_text("# Other page\n\n## A `code` heading: (2D)\n\n## Twice\n\n## Twice\n")
    page = tmp_path / "page.md"
    page.write_text("# Page\n\n[ok](other.md) [ok](other.md#a-code-heading-2d) [ok](other.md#twice-1)\n"
                    "[ok](#page) [web](https://example.org/x.md)\n[gone](missing.md) [no](other.md#nowhere)\n"
                    "`[in code](missing2.md)`\n\n    [indented](missing3.md)\n\n```\n[fenced](missing4.md)\n```\n")
    assert broken_links(page) == [("missing.md", "no such file"), ("other.md#nowhere", "no such heading")]


def python_blocks(path):
    return re.findall(r"^```python\n(.*?)^```", path.read_text(encoding="utf-8"), re.S | re.M)


def test_the_readme_script_is_the_getting_started_script_and_uses_exported_names():
    """The README's script is run by hand when the docs change; here it stays one text with the
    getting-started page's copy, compiles, and names only what pardem exports (a renamed API
    name fails here without running the script)."""
    import pardem

    readme = python_blocks(ROOT / "README.md")
    assert len(readme) == 1 and readme == python_blocks(ROOT / "docs" / "getting-started.md")[:1]
    compile(readme[0], "README.md", "exec")
    names = set(re.findall(r"\bpardem\.([A-Za-z_]\w*)", readme[0]))
    assert names and sorted(n for n in names if n not in pardem.__all__) == []
