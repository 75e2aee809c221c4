"""The documentation: the MkDocs site builds with warnings as errors, and the README holds.

The site (``mkdocs.yml``, pages in ``docs/``, API reference by mkdocstrings from the sources)
is built into a temporary folder with ``--strict``: a broken link or anchor, a page left out of
the navigation or a docstring mkdocstrings cannot read fails the test with MkDocs' own lines.
The README is checked for what CI and a newcomer rely on: the two set-up commands verbatim,
every local link and image resolving, and its length.
"""

from __future__ import annotations

import importlib.util
import os
import pkgutil
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import excavator_payload

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

#: The README's set-up commands; .ci/run runs them (less the demo) and a newcomer copies them.
SETUP = ('python3.11 -m venv .venv && .venv/bin/pip install -e ".[test]" && .venv/bin/excavator-payload demo',
         ".venv/bin/python -m pytest")

#: "A README a newcomer reads in five minutes": the developers' guide says at most ~300 lines.
README_MAX_LINES = 300
#: ... of prose a reader can follow: a line count means nothing if a paragraph is one line.
#: Tables, images, code and lines that are only a link are exempt.
README_MAX_PROSE_WIDTH = 140


def _mkdocs_missing() -> str | None:
    for module in ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python"):
        if importlib.util.find_spec(module.split(".")[0]) is None or importlib.util.find_spec(module) is None:
            return (f"{module} is not installed: pip install -e \".[docs]\" (the test extra includes it) "
                    "to build the documentation site")
    return None


def test_site_builds_strict(tmp_path):
    """`mkdocs build --strict` passes: no warning of any kind (links, anchors, nav, docstrings)."""
    missing = _mkdocs_missing()
    if missing:
        pytest.skip(missing)
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    built = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict",
                            "--config-file", str(ROOT / "mkdocs.yml"), "--site-dir", str(tmp_path / "site")],
                           cwd=ROOT, capture_output=True, text=True, env=env, timeout=300)
    warnings = [line for line in (built.stdout + built.stderr).splitlines() if "WARNING" in line or "ERROR" in line]
    assert built.returncode == 0 and not warnings, "\n".join(warnings) or built.stderr[-3000:]
    # The pages a newcomer needs exist in the built site, the API reference with real content.
    site = tmp_path / "site"
    for page in ("index.html", "getting-started/index.html", "guide/machine/index.html",
                 "findings/thesis/index.html", "api/estimators/index.html"):
        assert (site / page).is_file(), page
    api = (site / "api/estimators/index.html").read_text(encoding="utf-8")
    assert "excavator_payload.estimators.base" in api and "Parameters" in api


def _nav_pages() -> set[str]:
    text = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    nav = text.split("\nnav:", 1)[1].split("\n\n", 1)[0]
    return set(re.findall(r"([\w./-]+\.md)\s*$", nav, flags=re.M))


def test_every_subpackage_has_an_api_page():
    """A new subpackage gets its page: the API reference is complete, not a hand-kept subset."""
    subpackages = {info.name for info in pkgutil.iter_modules(excavator_payload.__path__)
                   if info.ispkg and not info.name.startswith("_")}
    subpackages -= {"studies"}  # shipped TOML files, no code
    pages = {p.name.removesuffix(".md") for p in (ROOT / "docs/api").glob("*.md")}
    assert subpackages <= pages, f"no docs/api page for {sorted(subpackages - pages)}"
    nav = _nav_pages()
    assert {f"api/{name}.md" for name in subpackages} <= nav, "add the API page to mkdocs.yml's nav"
    for name in subpackages:
        assert f"::: excavator_payload.{name}" in (ROOT / f"docs/api/{name}.md").read_text(encoding="utf-8")


def test_readme_setup_commands_verbatim():
    """The README opens with the two commands, exactly as .ci/run and a newcomer use them."""
    text = README.read_text(encoding="utf-8")
    first_block = re.search(r"```bash\n(.*?)```", text, flags=re.S)
    assert first_block is not None, "the README has no bash block"
    assert tuple(first_block.group(1).strip().splitlines()) == SETUP
    assert text.index(first_block.group(0)) < text.index("\n## "), "the commands come before the first section"
    ci = (ROOT / ".ci/run").read_text(encoding="utf-8")
    assert '.venv/bin/pip install -q -e ".[test]"' in ci and "\n.venv/bin/python -m pytest" in ci


def _local_links(text: str) -> list[str]:
    links = re.findall(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)", text)
    links += re.findall(r"<img[^>]+src=\"([^\"]+)\"", text)
    return [link for link in links if not re.match(r"[a-z][a-z0-9+.-]*:", link) and not link.startswith("#")]


def _anchors(markdown: str) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    anchors = set()
    for heading in re.findall(r"^#{1,6}\s+(.*?)\s*$", markdown, flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", heading.lower().replace("`", "")).replace(" ", "-")
        anchors.add(slug)
    return anchors


def test_readme_links_resolve():
    """Every local link and image of the README points at a file of the repository (and, for a
    link into a Markdown page with an anchor, at one of its headings)."""
    text = README.read_text(encoding="utf-8")
    links = _local_links(text)
    assert any(link.startswith("docs/figures/") for link in links), "the README shows the headline figures"
    broken = []
    for link in links:
        path, _, anchor = link.partition("#")
        target = (README.parent / path).resolve()
        if not target.exists():
            broken.append(f"{link}: no such file")
        elif anchor and target.suffix == ".md" and anchor not in _anchors(target.read_text(encoding="utf-8")):
            broken.append(f"{link}: no heading with that anchor")
    assert not broken, "\n".join(broken)


def test_readme_points_into_the_site():
    """The README stays short and sends the reader to the documentation for the rest."""
    text = README.read_text(encoding="utf-8")
    lines = text.count("\n")
    assert lines <= README_MAX_LINES, f"README.md has {lines} lines; move findings and details to docs/"
    in_code, wide = False, []
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            in_code = not in_code
        exempt = in_code or line.startswith(("|", "![", "([", "[")) or line.startswith("```")
        if not exempt and len(line) > README_MAX_PROSE_WIDTH:
            wide.append(number)
    assert not wide, f"README.md prose lines {wide} are wider than {README_MAX_PROSE_WIDTH} characters: wrap them"
    linked_pages = {link.partition("#")[0] for link in _local_links(text) if link.endswith(".md") or ".md#" in link}
    assert {"docs/getting-started.md", "docs/guide/machine.md", "docs/findings/index.md"} <= linked_pages
    assert "mkdocs serve" in text
    # The README speaks to a user: no release jargon, no issue numbers the user cannot see.
    for phrase in ("this release", "last release", "previous release"):
        assert phrase not in text.lower(), phrase
    assert not re.search(r"\bissue\s+#?\d+", text, flags=re.I)


def test_docs_are_written_for_a_user():
    """The documentation pages say "measured when", not "this release"; no issue numbers."""
    offenders = []
    for page in sorted((ROOT / "docs").rglob("*.md")):
        text = page.read_text(encoding="utf-8").lower()
        for phrase in ("this release", "last release", "previous release", "release by release"):
            if phrase in text:
                offenders.append(f"{page.relative_to(ROOT)}: {phrase!r}")
        if re.search(r"\bissue\s+#?\d+", text):
            offenders.append(f"{page.relative_to(ROOT)}: an issue number")
    assert not offenders, "\n".join(offenders)


@pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")
def test_site_output_is_ignored():
    """`mkdocs build` writes site/; it must not end up in a commit."""
    ignored = subprocess.run(["git", "check-ignore", "-q", "site/index.html"], cwd=ROOT)
    if ignored.returncode == 128:
        pytest.skip("not a git checkout")
    assert ignored.returncode == 0, "add /site/ to .gitignore"
