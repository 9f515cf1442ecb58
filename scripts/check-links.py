#!/usr/bin/env python3
"""Broken links fail CI: every link of the built book and of the README must reach a file, and
every #fragment an anchor in it.

Usage: python3 scripts/check-links.py [BOOK_DIR]   (default docs/book, built by `mdbook build docs`)

- The book: every href/src of every built page (what a reader clicks, after mdBook turned the
  .md links into .html) must name a file inside the book, and a #fragment an id in that page.
  Links to other sites (https://…) are allowed in the book and listed, not fetched (CI has no
  network).
- README.md: its links must stay inside the repository (no other sites, no ../), name a file
  that exists, and a #fragment a heading of that markdown file.

Our own checker rather than mdbook-linkcheck: that backend was last released in 2022 against
mdBook 0.4's renderer interface, and it builds an HTTP client that CI, without network, cannot use.
"""
import html.parser
import pathlib
import re
import sys
import urllib.parse

ROOT = pathlib.Path(__file__).resolve().parent.parent
EXTERNAL = re.compile(r"^[a-z][a-z0-9+.-]*:", re.I)


class Page(html.parser.HTMLParser):
    """The links and the anchors of one HTML page."""

    def __init__(self):
        super().__init__()
        self.links, self.ids = [], set()

    def handle_starttag(self, tag, attrs):
        for name, value in attrs:
            if name in ("id", "name") and value:
                self.ids.add(value)
            if value and ((name == "href" and tag in ("a", "link")) or (name == "src" and tag in ("img", "script"))):
                self.links.append(value)


def parse(path):
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    return page


def check_book(book):
    problems, external = [], set()
    pages = {p.resolve(): parse(p) for p in book.rglob("*.html") if p.name != "print.html"}
    for path, page in sorted(pages.items()):
        for link in page.links:
            if EXTERNAL.match(link):
                if not link.startswith("javascript:"):
                    external.add(link)
                continue
            target, _, fragment = link.partition("#")
            target = urllib.parse.unquote(target.split("?")[0])
            resolved = (path.parent / target).resolve() if target else path
            if resolved.is_dir():
                resolved = resolved / "index.html"
            where = f"{path.relative_to(book.resolve())}: {link}"
            if book.resolve() not in resolved.parents:
                problems.append(f"{where}: points outside the book")
            elif not resolved.exists():
                problems.append(f"{where}: no such file")
            elif fragment and resolved.suffix == ".html":
                ids = pages[resolved].ids if resolved in pages else parse(resolved).ids
                if urllib.parse.unquote(fragment) not in ids:
                    problems.append(f"{where}: no anchor #{fragment} in {resolved.name}")
    return problems, external, len(pages)


def slug(heading):
    """GitHub's anchor of a markdown heading."""
    text = re.sub(r"[`*_]", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def markdown_links(text):
    """(line, target) of the inline links outside fenced code."""
    found, fenced = [], False
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if not fenced:
            line = re.sub(r"`[^`]*`", "", line)
            found += [(number, m.group(1)) for m in re.finditer(r"\]\(([^)\s]+)\)", line)]
    return found


def check_readme():
    problems = []
    readme = ROOT / "README.md"
    for line, link in markdown_links(readme.read_text(encoding="utf-8")):
        where = f"README.md:{line}: {link}"
        if EXTERNAL.match(link):
            problems.append(f"{where}: the README links only into the repository")
            continue
        target, _, fragment = link.partition("#")
        resolved = (ROOT / urllib.parse.unquote(target)).resolve() if target else readme
        if ROOT not in resolved.parents and resolved != ROOT:
            problems.append(f"{where}: points outside the repository")
        elif not resolved.exists():
            problems.append(f"{where}: no such file")
        elif fragment and resolved.suffix == ".md":
            headings = [slug(h) for h in re.findall(r"^#+ (.*)$", resolved.read_text(encoding="utf-8"), re.M)]
            if fragment not in headings:
                problems.append(f"{where}: no heading #{fragment} in {resolved.name}")
    return problems


def main():
    book = pathlib.Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "book"
    if not (book / "index.html").exists():
        sys.exit(f"{book}: no built book (run `mdbook build docs` first)")
    problems, external, pages = check_book(book)
    problems += check_readme()
    for problem in problems:
        print(f"broken link: {problem}")
    print(f"links checked in {pages} book pages and README.md: {len(problems)} broken; "
          f"{len(external)} links to other sites not fetched")
    sys.exit(1 if problems else 0)


if __name__ == "__main__":
    main()
