"""Every relative link in the README, docs/, research/ and results/ resolves: the file
exists, and an anchor names a heading of the page it points to (GitHub's slugs)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.conftest import COMPILED_GROUP

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
         *sorted((ROOT / "research").rglob("*.md")), *sorted((ROOT / "results").rglob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")
CODE = re.compile(r"```.*?```", re.S)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = CODE.sub("", page.read_text())
    return {slug(line.lstrip("#")) for line in text.splitlines() if line.startswith("#")}


def links(page: Path) -> list[str]:
    return [target for target in LINK.findall(CODE.sub("", page.read_text()))
            if not re.match(r"[a-z]+:", target)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_resolves(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists():
            broken.append(target)
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: {broken}"


def test_the_slugs_are_githubs():
    assert slug("Results: 12M frames of `fast` on this 2-core CPU — above Table 2") \
        == "results-12m-frames-of-fast-on-this-2-core-cpu--above-table-2"
    assert slug("Usage with TorchRL") == "usage-with-torchrl"


def test_ci_runs_the_readmes_two_commands_as_written():
    """The README's first screen gives the set-up and test commands; CI runs them verbatim
    (so a command that stops working on a fresh machine fails CI)."""
    block = re.search(r"```bash\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    commands = [line for line in block.splitlines() if line and not line.startswith("#")]
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert len(commands) == 2 and all(command in ci for command in commands)


@pytest.mark.xdist_group(COMPILED_GROUP)
def test_the_tests_of_one_xdist_group_share_a_worker(request):
    """The README: on the suite's workers the tests that compile the shared builds run on one
    of them. pytest-xdist's loadgroup tags their node ids with the group; where it does not
    (pytest 9.2, pytest-xdist issue #1386) the groups split silently."""
    if not getattr(request.config.option, "loadgroup", False):  # set in xdist's workers
        pytest.skip("no --dist loadgroup workers (-n 0, or another --dist)")
    assert request.node.nodeid.endswith(f"@{COMPILED_GROUP}")


def test_the_readme_is_a_guide_of_at_most_12_kb_with_its_contents():
    """The README guides; the reference and the details live on the site (docs/): at most
    12,000 bytes, and its contents list links every section."""
    readme = (ROOT / "README.md").read_text()
    assert len(readme.encode()) <= 12_000
    sections = [slug(line[3:]) for line in readme.splitlines() if line.startswith("## ")]
    contents = next(line for line in readme.split("\n\n") if line.startswith("Contents:"))
    assert [s for s in sections if s != "citation" and f"(#{s})" not in contents] == []
