"""The documentation stands on its own: every relative link resolves to a file in the repository,
and every `#anchor` to a heading of that file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted([ROOT / "README.md", ROOT / "CHANGELOG.md", *(ROOT / "docs").rglob("*.md")])

_FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
_CODE = re.compile(r"`[^`\n]*`")
_INLINE = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+[\"'][^)]*[\"'])?\s*\)")
_REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", re.M)


def relative_links(markdown: str) -> list[str]:
    """Link targets outside code, without ``#anchor``; web and mail links left out."""
    text = _CODE.sub("", _FENCE.sub("", markdown))
    targets = _INLINE.findall(text) + _REFERENCE.findall(text)
    out = []
    for target in targets:
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or target.startswith("#"):
            continue
        out.append(target.split("#", 1)[0])
    return out


def test_link_parser() -> None:
    md = (
        '[a](docs/x.md#part) ![img](img/p.png "title") [w](https://e.org) [s](#here)\n'
        "`[not](code.md)`\n```\n[no](fenced.md)\n```\n[ref]: ../outside.md\n"
    )
    assert relative_links(md) == ["docs/x.md", "img/p.png", "../outside.md"]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves_inside_the_repository(doc: Path) -> None:
    broken = []
    for target in relative_links(doc.read_text()):
        path = (doc.parent / target).resolve()
        if ROOT not in path.parents and path != ROOT:
            broken.append(f"{target} (outside the repository)")
        elif not path.exists():
            broken.append(f"{target} (no such file)")
    assert not broken, f"{doc.relative_to(ROOT)}: broken links: {', '.join(broken)}"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_reference_to_files_outside_the_repository(doc: Path) -> None:
    """Plain-text mentions count too: ``../shared/...`` and the design notes are not shipped."""
    text = doc.read_text()
    for needle in ("../shared", "DESIGN.md", "RECIPES.md", "PERFORMANCE.md", "amor-paper.tex"):
        assert needle not in text, f"{doc.relative_to(ROOT)} refers to {needle!r} (not in the repository)"


def test_the_observation_table_is_the_one_layout_definition() -> None:
    """docs/observations.md lists the observation's terms and sizes in the order and with the
    sizes of amorctl.core.observation.OBSERVATION_TERMS, which every tracking env builds from."""
    from amorctl.core.observation import OBSERVATION_TERMS, observation_layout

    text = (ROOT / "docs" / "observations.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \| ([^|]+) \|", text, flags=re.MULTILINE)
    assert [(name, size.strip()) for name, size in rows] == list(OBSERVATION_TERMS)
    layout = observation_layout(101, 20, 16, (5, 25), 7)  # biped20, L = 16, two future frames
    assert list(layout) == [name for name, _ in OBSERVATION_TERMS]
    assert [s.stop - s.start for s in layout.values()] == [101, 40, 101, 16, 202, 7]
    assert layout["weights"].stop == 101 + 40 + 101 + 16 + 202 + 7  # contiguous, w last


_HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$", re.M)


def heading_anchors(markdown: str) -> set[str]:
    """The ``#anchor`` names a markdown file offers: GitHub's heading slugs (lower case, punctuation
    dropped, spaces to hyphens, ``-1``, ``-2`` ... for repeats) and explicit ``<a id=...>``."""
    text = _FENCE.sub("", markdown)
    seen: dict[str, int] = {}
    out = set(re.findall(r"<a\s+(?:id|name)=\"([^\"]+)\"", text))
    for heading in _HEADING.findall(text):
        slug = re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
        out.add(slug if slug not in seen else f"{slug}-{seen[slug]}")
        seen[slug] = seen.get(slug, 0) + 1
    return out


def test_heading_anchors() -> None:
    md = "# Where the motors run out, while it tries\n## `run` alone\n## Notes\n## Notes\n```\n# no\n```\n"
    expected = {"where-the-motors-run-out-while-it-tries", "run-alone", "notes", "notes-1"}
    assert heading_anchors(md) == expected


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_anchor_names_a_heading_of_its_file(doc: Path) -> None:
    text = _CODE.sub("", _FENCE.sub("", doc.read_text()))
    broken = []
    for target in _INLINE.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I) or "#" not in target:
            continue
        file, anchor = target.split("#", 1)
        path = (doc.parent / file).resolve() if file else doc
        if path.suffix == ".md" and path.exists() and anchor not in heading_anchors(path.read_text()):
            broken.append(target)
    assert not broken, f"{doc.relative_to(ROOT)}: links to headings that do not exist: {', '.join(broken)}"
