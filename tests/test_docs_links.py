"""Every relative link in the README and the docs reaches a file of the repository, and every
``#fragment`` one of that page's headings as GitHub names them: a renamed heading or a moved
page shows up here, not as a dead link in a reader's browser."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$")


def _pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: its text (links and code marks as shown) in lower case,
    without punctuation but ``-`` and ``_``, spaces as ``-``."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "")
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


@cache
def anchors(page: Path) -> frozenset[str]:
    """The anchors of ``page``'s headings (outside code blocks); a repeated one gets ``-1``,
    ``-2``, ... as on GitHub."""
    found, seen, code = set(), {}, False
    for line in page.read_text().splitlines():
        if line.lstrip().startswith("```"):
            code = not code
        elif not code and (m := HEADING.match(line)):
            s = slug(m.group(1))
            n = seen.get(s, 0)
            seen[s] = n + 1
            found.add(s if n == 0 else f"{s}-{n}")
    return frozenset(found)


def dead_links(page: Path, root: Path = ROOT) -> list[str]:
    """``page:line -> target`` for each relative link of ``page`` (outside code blocks, which
    show no links) that reaches no file, or no heading of the page it names."""
    dead, code = [], False
    for number, line in enumerate(page.read_text().splitlines(), 1):
        if line.lstrip().startswith("```"):
            code = not code
        for target in [] if code else LINK.findall(line):
            if re.match(r"[a-z]+:", target):  # https:, mailto:
                continue
            path, _, fragment = target.partition("#")
            reached = (page.parent / path) if path else page
            if not reached.exists() or (
                fragment and reached.suffix == ".md" and fragment not in anchors(reached.resolve())
            ):
                dead.append(f"{page.relative_to(root)}:{number} -> {target}")
    return dead


def test_slug_is_githubs() -> None:
    assert slug("Results: the paper's tables") == "results-the-papers-tables"
    assert slug("`quick` profile: the whole grid, shortened — [full report](quick/report.md)") == (
        "quick-profile-the-whole-grid-shortened--full-report"
    )


def test_every_relative_link_reaches_its_file_and_heading() -> None:
    dead = [d for page in _pages() for d in dead_links(page)]
    assert not dead, "dead links:\n" + "\n".join(dead)


def test_a_dead_link_is_found(tmp_path: Path) -> None:
    (tmp_path / "other.md").write_text("# A heading\n```\n# not a heading\n```\n")
    page = tmp_path / "page.md"
    page.write_text(
        "[ok](other.md#a-heading) [no heading](other.md#not-a-heading) [no file](gone.md)\n"
        "```\n[in code](nowhere.md)\n```\n[here](#up) ![image](img.png)\n# Up\n"
    )
    assert dead_links(page, tmp_path) == [
        "page.md:1 -> other.md#not-a-heading",
        "page.md:1 -> gone.md",
        "page.md:5 -> img.png",
    ]
