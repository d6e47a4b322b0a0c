"""The documentation in docs/: pages stay specifications (no scratch paths, no diary dates, at most 400
lines), every relative link and anchor resolves, and, where MkDocs is installed, the site builds with
``mkdocs build --strict`` (warnings, broken links and anchors included, are errors)."""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import unicodedata

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DOCS = os.path.join(ROOT, "docs")
MAX_LINES = 400
PAGES = sorted(f for f in os.listdir(DOCS) if f.endswith(".md"))

SCRATCH_PATH = re.compile(r"/tmp/")
DATE = re.compile(r"\b(19|20)\d\d-(0[1-9]|1[0-2])-(0[1-9]|[12]\d|3[01])\b")
FENCE = re.compile(r"^\s*(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
CODE_SPAN = re.compile(r"(`+)(.+?)\1")
# [text](target "title") and ![alt](target); nested brackets in the text are rare enough to ignore
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
ATTR_ID = re.compile(r"\{[^}]*#([\w-]+)[^}]*\}")


def _read(name: str) -> str:
    with open(os.path.join(DOCS, name), encoding="utf-8") as f:
        return f.read()


def _prose_lines(text: str):
    """(line number, line) outside fenced code blocks."""
    fenced = False
    for i, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield i, line


def slugify(title: str) -> str:
    """Python-Markdown's toc slug (what MkDocs gives a heading as its id)."""
    title = re.sub(r"<[^>]+>", "", title)
    title = CODE_SPAN.sub(lambda m: m.group(2), title)
    title = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", title)  # a link's text
    title = unicodedata.normalize("NFKD", title).encode("ascii", "ignore").decode("ascii")
    title = re.sub(r"[^\w\s-]", "", title).strip().lower()
    return re.sub(r"[-\s]+", "-", title)


def _page_text(name: str) -> str:
    """The page as MkDocs renders it: cli.md with its generated reference where the parsers import, formats.md with
    the field tables of the JSON schemas."""
    text = _read(name)
    if name == "formats.md":
        sys.path.insert(0, DOCS)
        try:
            import gen_formats
            text = gen_formats.expand(text)
        finally:
            sys.path.remove(DOCS)
    if name == "cli.md":
        sys.path.insert(0, DOCS)
        try:
            import gen_cli
            if gen_cli.MARKER in text and importlib.util.find_spec("material_structures") is not None:
                text = text.replace(gen_cli.MARKER, gen_cli.render())
        finally:
            sys.path.remove(DOCS)
    return text


def anchors(text: str) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    for _, line in _prose_lines(text):
        m = HEADING.match(line)
        if m:
            explicit = ATTR_ID.search(m.group(2))
            slug = explicit.group(1) if explicit else slugify(ATTR_ID.sub("", m.group(2)))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            out.add(slug if n == 0 else f"{slug}_{n}")
        out.update(re.findall(r"<a\s+(?:name|id)=\"([^\"]+)\"", line))
    return out


def links(text: str):
    """(line number, target) of every Markdown link outside code."""
    for i, line in _prose_lines(text):
        for m in LINK.finditer(CODE_SPAN.sub("", line)):
            yield i, m.group(1)


@pytest.mark.parametrize("name", PAGES)
def test_page_is_a_specification_not_a_diary(name):
    text = _read(name)
    lines = text.splitlines()
    assert len(lines) <= MAX_LINES, f"docs/{name}: {len(lines)} lines (at most {MAX_LINES}); split the page"
    for i, line in enumerate(lines, 1):
        assert not SCRATCH_PATH.search(line), f"docs/{name}:{i}: names a scratch path: {line.strip()}"
        assert not DATE.search(line), f"docs/{name}:{i}: dates its text (the history lives in git): {line.strip()}"


@pytest.mark.parametrize("name", PAGES)
def test_relative_links_and_anchors_resolve(name):
    text = _page_text(name)
    for i, target in links(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):  # http:, mailto:, ...
            continue
        assert not target.startswith("/"), f"docs/{name}:{i}: absolute link {target!r}; link relative to docs/"
        path, _, anchor = target.partition("#")
        dest = name if not path else os.path.normpath(os.path.join(os.path.dirname(name), path))
        full = os.path.join(DOCS, dest)
        assert os.path.isfile(full), f"docs/{name}:{i}: link to {target!r}: docs/{dest} does not exist"
        assert os.path.abspath(full).startswith(DOCS + os.sep), f"docs/{name}:{i}: {target!r} leaves docs/"
        if anchor:
            assert dest.endswith(".md"), f"docs/{name}:{i}: anchor on a non-page {target!r}"
            dest_text = _page_text(dest)
            if "<!-- cli-reference -->" in dest_text:  # the parsers did not import: its headings are unknown
                continue
            assert anchor in anchors(dest_text), f"docs/{name}:{i}: no heading #{anchor} in docs/{dest}"


@pytest.mark.parametrize("name", PAGES)
def test_table_rows_keep_their_columns(name):
    """A stray | inside a cell (write abs(x), or \\| ) splits the row and shifts every cell after it."""
    width = None
    for i, line in _prose_lines(_page_text(name)):
        if not line.startswith("|"):
            width = None
            continue
        cells = len(CODE_SPAN.sub("", line).replace("\\|", "").split("|"))
        width = width or cells
        assert cells == width, f"docs/{name}:{i}: {cells - 2} cells where the table has {width - 2}"


def test_the_checker_sees_broken_links_and_diary_text():
    title = "Teeth fit: what it recovers (and what it cannot)"
    assert slugify(title) == "teeth-fit-what-it-recovers-and-what-it-cannot"
    assert slugify("`teeth fit` options") == "teeth-fit-options"
    text = "# A\n## A\n```\n# not a heading [x](nowhere.md)\n```\n[y](b.md#c) `[z](q.md)`\n"
    assert anchors(text) == {"a", "a_1"}
    assert list(links(text)) == [(6, "b.md#c")]
    assert DATE.search("measured 2026-12-05") and not DATE.search("commit 2026125")


def test_readme_links_into_docs_resolve():
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        readme = f.read()
    for target in set(re.findall(r"\b(docs/[\w./-]+\.(?:md|png))", readme)):
        assert os.path.isfile(os.path.join(ROOT, target)), f"README.md names {target}, which does not exist"


@pytest.mark.skipif(importlib.util.find_spec("mkdocs") is None, reason="mkdocs is not installed")
def test_mkdocs_build_strict(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                           "--site-dir", str(tmp_path / "site")], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout}\n{proc.stderr}"
    assert (tmp_path / "site" / "index.html").is_file()
