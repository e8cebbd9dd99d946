"""The manual's structure, cheaply (the strict build itself runs in .ci/run): every page is in the
navigation and every navigation entry exists, every snippet a page includes names a report section
that exists, and figures stay where they live (the generated reports and the decision pages), not in
the code's docstrings or the manual's prose pages."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
SNIPPET = re.compile(r'^--8<-- "([^":]+)(?::([\w-]+))?"\s*$', re.M)
# A figure: a decimal number with four or more significant digits (97.81, 0.3667). Parameters and
# the paper's own figures (2.6, 6.8 %) are shorter; measured figures are what this rule keeps out.
FIGURE = re.compile(r"(?<![\w.])\d+\.\d+(?![\w.]*\d)")
CONSTANTS = {"1.4826", "1.2533", "0.975"}  # MAD to sigma; sqrt(pi / 2) for a median; FAST-MCD's reweighting quantile
CODE = re.compile(r"^```.*?^```", re.S | re.M)  # code blocks: their printed answers are run, not copied
# Pages that include or link figures and never hold their own (others' pages and the README's
# moved sections keep theirs until their owners move them).
PROSE = ("index.md", "accuracy.md", "method.md", "speed.md", "guides/source.md", "guides/measurement.md",
         "decisions/index.md")


def nav_pages(entries) -> list[str]:
    out = []
    for entry in entries:
        for value in (entry.values() if isinstance(entry, dict) else [entry]):
            out += nav_pages(value) if isinstance(value, list) else [value]
    return out


def figures(text: str) -> set[str]:
    """The measured figures in ``text``, code blocks left out."""
    found = {m.group() for m in FIGURE.finditer(CODE.sub("", text)) if sum(c.isdigit() for c in m.group()) >= 4}
    return found - CONSTANTS


def test_every_page_is_in_the_navigation_or_the_decisions_index():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    listed = nav_pages(config["nav"])
    pages = sorted(str(p.relative_to(DOCS)) for p in DOCS.rglob("*.md"))
    assert sorted(set(listed)) == sorted(listed), "a page listed twice"
    assert [p for p in listed if p not in pages] == [], "navigation entries without a page"
    # decision pages are reached from their index (one row each), every other page from the nav
    index = (DOCS / "decisions" / "index.md").read_text()
    unlisted = [p for p in pages if p not in listed]
    assert [p for p in unlisted if not p.startswith("decisions/")] == [], "pages missing from mkdocs.yml's nav"
    assert [p for p in unlisted if f"]({p.removeprefix('decisions/')})" not in index] == [], "decision pages missing from decisions/index.md"


def test_every_snippet_names_an_existing_section():
    seen = 0
    for page in DOCS.rglob("*.md"):
        for path, section in SNIPPET.findall(page.read_text()):
            target = (ROOT / path).read_text()
            seen += 1
            if section:
                assert f"--8<-- [start:{section}]" in target and f"--8<-- [end:{section}]" in target, (page, path, section)
    assert seen >= 10


def test_prose_pages_hold_no_figures():
    found = {page: figures((DOCS / page).read_text()) for page in PROSE}
    assert {p: f for p, f in found.items() if f} == {}


def module_docstrings(package: str):
    for path in sorted((ROOT / package).rglob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text()), clean=False)
        if doc:
            yield path.relative_to(ROOT), doc


def test_module_docstrings_say_what_not_what_was_measured():
    """No measured figure, no "issue #N" and at most 40 lines in the module docstrings of measure/,
    sim/ and evaluation/ (the reasons live in docs/decisions/, the figures in the reports)."""
    wrong = []
    for package in ("measure", "sim", "evaluation"):
        for path, doc in module_docstrings(package):
            if doc.count("\n") + 1 > 40:
                wrong.append(f"{path}: {doc.count(chr(10)) + 1} lines")
            if figures(doc):
                wrong.append(f"{path}: figures {sorted(figures(doc))}")
            if re.search(r"issue\s*#?\d", doc, re.I):
                wrong.append(f"{path}: an issue number")
    assert wrong == []


def test_the_figure_rule_finds_a_copied_figure():
    assert figures("robust 97.81 (median 98.82), 1.5 px, +2.6 points, 1.4826 MAD") == {"97.81", "98.82"}
    assert figures("```pycon\n>>> print(m.distance_m)\n0.3667\n```\n") == set()
