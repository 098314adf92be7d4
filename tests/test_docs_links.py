"""The README is a front page: at most 200 lines, every relative link resolves (file and heading,
as GitHub and mkdocs name headings), and every results row links to its results page section.
The design page names every layer of ``tests/test_layering.py``. Needs no mkdocs.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

from test_layering import LAYERS

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
LINK = re.compile(r"\]\(([^)\s]+)\)")


def github_slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, each space a hyphen."""
    text = heading.replace("`", "").replace("*", "").lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def mkdocs_slug(heading: str) -> str:
    """Python-Markdown's ``toc`` anchor (mkdocs' default): ASCII, runs of spaces/hyphens joined."""
    text = heading.replace("`", "")
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def headings(path: Path) -> list[str]:
    """Markdown headings of a file, outside code fences."""
    out, fence = [], False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.lstrip().startswith("```"):
            fence = not fence
        elif not fence and (m := re.match(r"^#{1,6}\s+(.*?)\s*$", line)):
            out.append(m.group(1))
    return out


def test_readme_is_a_front_page() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200
    for section in ("## Install and try", "## Quick start on the shared data", "## Results",
                    "## Commands", "## Why each dependency is there", "## Known limitations",
                    "## Where to go next"):  # fmt: skip
        assert section in lines, section
    assert "make demo" in README.read_text() and "make test" in README.read_text()


def test_readme_links_resolve() -> None:
    text = README.read_text(encoding="utf-8")
    bad = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z]+://", target):
            continue
        path, _, anchor = target.partition("#")
        file = ROOT / path
        if not file.exists():
            bad.append(f"{target}: no such file")
        elif anchor:
            names = headings(file)
            if anchor not in {github_slug(h) for h in names}:
                bad.append(f"{target}: no heading with that GitHub anchor")
            if anchor not in {mkdocs_slug(h) for h in names}:
                bad.append(f"{target}: no heading with that mkdocs anchor")
    assert bad == []


def test_every_readme_figure_links_to_its_results_section() -> None:
    """Each row of the README's results tables that shows a number links into docs/results/."""
    text = README.read_text(encoding="utf-8")
    results = text.split("\n## Results\n")[1].split("\n## ")[0]
    rows = [r for r in results.splitlines()
            if r.startswith("|") and not set(r) <= set("|-: ")]  # fmt: skip
    data_rows = [r for r in rows if re.search(r"\d", r) and "](docs/results/" not in r]
    header_rows = [r for r in data_rows if r.startswith("| experiment |")
                   or r.startswith("| measurement |")]  # fmt: skip
    assert [r for r in data_rows if r not in header_rows] == []
    assert len(rows) >= 20


def test_slugs() -> None:
    heading = "The paper's experiments on the simulated village (`svains demo`, 2026-12-02)"
    expected = "the-papers-experiments-on-the-simulated-village-svains-demo-2026-12-02"
    assert github_slug(heading) == mkdocs_slug(heading) == expected
    assert github_slug("a + b") == "a--b" and mkdocs_slug("a + b") == "a-b"


def test_design_page_names_every_layer() -> None:
    design = ROOT / "docs" / "design"
    index = (design / "index.md").read_text(encoding="utf-8")
    pages = {p.stem for p in design.glob("*.md")} - {"index"}
    for layer in LAYERS:
        assert layer in index, layer
        assert any(layer == p or layer in (design / f"{p}.md").read_text(encoding="utf-8")
                   for p in pages), f"no design page for {layer}"  # fmt: skip
