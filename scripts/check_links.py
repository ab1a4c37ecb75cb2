#!/usr/bin/env python3
"""Check that the documentation's links resolve; exit 1 naming each one that does not.

Four checks, all offline:

1. The Markdown sources (``README.md`` and ``docs/src/**.md``): every relative link and image
   names a file or folder that exists, and every ``#anchor`` names a heading of its target page
   (ids made as mdBook makes them). A page of the book may link only inside ``docs/src``: the
   book publishes nothing else, so a link out of it would break in the HTML.
2. The book: every page under ``docs/src`` is in ``SUMMARY.md`` (mdBook renders no other), and
   every decision record in the index ``decisions.md``.
3. The built HTML (``mdbook build docs`` first): every relative ``href`` and ``src`` names a
   file of the book, and every fragment an ``id`` of its target page.
4. The code's citations: every ``docs/src/<page>.md`` named in a source file exists (comments
   cite decision records by path).

Usage: ``python3 scripts/check_links.py [--root DIR] [--book DIR]``.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from collections.abc import Iterator
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

# [text](target) and ![alt](target), with an optional "title"; the text may hold one level of
# brackets (a link around an image, or `a[i]` in code).
MD_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
# Raw HTML in Markdown: <img src="..."> and <a href="...">.
HTML_ATTR = re.compile(r"<(?:img|a)\b[^>]*?\b(?:src|href)=\"([^\"]+)\"", re.IGNORECASE)
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
FENCE = re.compile(r"^\s*(```|~~~)")
INLINE_CODE = re.compile(r"`+[^`]*`+")
# A page of the book named in a source file, e.g. docs/src/decisions/0001-impulse-joints.md.
DOC_CITATION = re.compile(r"docs/src/[A-Za-z0-9_./-]+\.md")
SOURCE_SUFFIXES = {".rs", ".py", ".toml", ".sh", ".proto", ".yaml", ".yml"}
# Build outputs, environments and caches: not sources.
SKIP_DIRS = {".git", "target", ".venv", "runs", "book", "node_modules", "__pycache__"}


def is_external(target: str) -> bool:
    """Whether ``target`` leaves the repository (a URL scheme such as https: or mailto:)."""
    return bool(urlsplit(target).scheme)


def slug(text: str) -> str:
    """The id mdBook gives a heading: its text lowercased, spaces to '-', punctuation dropped."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", text)  # links and images: their text
    text = re.sub(r"<[^>]+>", "", text)  # inline HTML tags
    text = text.replace("`", "").replace("*", "")
    out = []
    for ch in text.strip().lower():
        if ch.isalnum() or ch in "-_":
            out.append(ch)
        elif ch.isspace():
            out.append("-")
    return "".join(out)


def prose_lines(text: str) -> Iterator[tuple[int, str]]:
    """Numbered lines outside fenced code blocks, with inline code spans blanked out."""
    fenced = False
    for number, line in enumerate(text.splitlines(), start=1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield number, INLINE_CODE.sub("", line)


def heading_ids(page: Path) -> set[str]:
    """The anchors a Markdown page offers: its headings' ids, numbered as mdBook numbers repeats."""
    ids: set[str] = set()
    counts: dict[str, int] = {}
    for _, line in prose_lines(page.read_text(encoding="utf-8")):
        match = HEADING.match(line)
        if not match:
            continue
        base = slug(match.group(2))
        n = counts.get(base, 0)
        counts[base] = n + 1
        ids.add(base if n == 0 else f"{base}-{n}")
    return ids


def check_markdown(page: Path, root: Path, book_src: Path, errors: list[str]) -> None:
    """Check the relative links and anchors of one Markdown page."""
    in_book = book_src in page.parents
    for number, line in prose_lines(page.read_text(encoding="utf-8")):
        targets = [m.group(1) for m in MD_LINK.finditer(line)]
        targets += [m.group(1) for m in HTML_ATTR.finditer(line)]
        for target in targets:
            if is_external(target):
                continue
            where = f"{page.relative_to(root)}:{number}: {target}"
            path_part, _, anchor = target.partition("#")
            # normpath, not resolve: a symlink inside the book (docs/src/pictures) is published.
            dest = Path(os.path.normpath(page.parent / unquote(path_part))) if path_part else page
            if not dest.exists():
                errors.append(f"{where}: no such file")
                continue
            if in_book and book_src not in [dest, *dest.parents]:
                errors.append(f"{where}: leaves docs/src, which the book does not publish")
                continue
            if anchor:
                if dest.suffix != ".md":
                    errors.append(f"{where}: an anchor into a file that is not a Markdown page")
                elif anchor not in heading_ids(dest):
                    errors.append(f"{where}: no heading with id '{anchor}' in {dest.name}")


def linked_pages(index: Path) -> set[Path]:
    """The local pages that ``index`` links to, as normalised paths."""
    return {
        Path(os.path.normpath(index.parent / unquote(m.group(1).partition("#")[0])))
        for m in MD_LINK.finditer(index.read_text(encoding="utf-8"))
    }


def check_summary(book_src: Path, root: Path, errors: list[str]) -> None:
    """Every page under the book's source is in SUMMARY.md; every decision record in its index."""
    listed = linked_pages(book_src / "SUMMARY.md")
    for page in sorted(book_src.rglob("*.md")):
        if page.name != "SUMMARY.md" and page not in listed:
            errors.append(f"{page.relative_to(root)}: not in SUMMARY.md, so not in the book")
    index = book_src / "decisions.md"
    if index.is_file():
        indexed = linked_pages(index)
        for record in sorted((book_src / "decisions").glob("*.md")):
            if record not in indexed:
                errors.append(f"{record.relative_to(root)}: not in the index {index.name}")


class _Anchors(HTMLParser):
    """Collects the ids of an HTML page and the relative URLs it refers to."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.refs: list[tuple[int, str]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value is None:
                continue
            if name in ("id", "name") and (name == "id" or tag == "a"):
                self.ids.add(value)
            elif name in ("href", "src") and tag in ("a", "img", "link", "script"):
                self.refs.append((self.getpos()[0], value))


def parse_html(page: Path) -> _Anchors:
    """The ids and references of one built page."""
    parser = _Anchors()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def check_html(book: Path, errors: list[str]) -> None:
    """Check every relative reference and fragment of the built book."""
    pages = {p.resolve(): parse_html(p) for p in book.rglob("*.html") if p.name != "404.html"}
    for page, parsed in sorted(pages.items()):
        for number, ref in parsed.refs:
            parts = urlsplit(ref)
            if parts.scheme or ref.startswith("//") or ref == "#":
                continue
            where = f"{page.relative_to(book.resolve())}:{number}: {ref}"
            dest = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            if dest.is_dir():
                dest = dest / "index.html"
            if not dest.exists():
                errors.append(f"{where}: no such file in the book")
            elif parts.fragment and dest.suffix == ".html":
                ids = pages[dest].ids if dest in pages else parse_html(dest).ids
                if unquote(parts.fragment) not in ids:
                    errors.append(f"{where}: no id '{parts.fragment}' in {dest.name}")


def check_citations(root: Path, errors: list[str]) -> None:
    """Every page of the book that a source file names exists."""
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if d not in SKIP_DIRS and not d.startswith(".")]
        for name in files:
            path = Path(folder) / name
            if path.suffix not in SOURCE_SUFFIXES:
                continue
            text = path.read_text(encoding="utf-8", errors="replace")
            for number, line in enumerate(text.splitlines(), start=1):
                for cited in DOC_CITATION.findall(line):
                    if not (root / cited).is_file():
                        errors.append(f"{path.relative_to(root)}:{number}: {cited}: no such page")


def main(argv: list[str] | None = None) -> int:
    """Run the checks; print every broken link; 0 when there is none."""
    here = Path(__file__).resolve().parent.parent
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=here, help="the repository (default: ours)")
    parser.add_argument("--book", type=Path, help="the built book (default: ROOT/docs/book)")
    args = parser.parse_args(argv)
    root = args.root.resolve()
    book_src = root / "docs" / "src"
    book = (args.book or root / "docs" / "book").resolve()

    errors: list[str] = []
    pages = [root / "README.md", *sorted(book_src.rglob("*.md"))]
    for page in pages:
        check_markdown(page, root, book_src, errors)
    check_summary(book_src, root, errors)
    check_citations(root, errors)
    if not (book / "index.html").exists():
        errors.append(f"{book}: no built book here (run `mdbook build docs` first)")
    else:
        check_html(book, errors)

    for error in errors:
        print(error, file=sys.stderr)
    html_pages = sum(1 for _ in book.rglob("*.html"))
    print(f"links: {len(pages)} Markdown pages, {html_pages} HTML pages, {len(errors)} broken")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
