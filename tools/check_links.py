"""Check every internal link of a built HTML site, offline: each relative ``href`` or
``src`` must name a file of the site, and each ``#anchor`` an ``id`` (or ``name``) in it.

``python tools/check_links.py docs/_build/html`` prints each broken link as
``page: href (why)`` and exits with 1 if there is one. External links (with a scheme,
``//host``, ``mailto:``) are not followed: the check needs no network.
"""

from __future__ import annotations

import sys
import urllib.parse
from collections.abc import Iterator
from html.parser import HTMLParser
from pathlib import Path


class _Page(HTMLParser):
    """The anchors (``id``/``name``) and the links (``href``/``src``) of one page."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.anchors: set[str] = set()
        self.links: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        for name, value in attrs:
            if value is None:
                continue
            if name == "id" or (name == "name" and tag == "a"):
                self.anchors.add(value)
            elif (name == "href" and tag in ("a", "link", "area")) or (
                    name == "src" and tag in ("img", "script", "iframe", "source")):
                self.links.append(value)


def _parse(path: Path) -> _Page:
    page = _Page()
    page.feed(path.read_text(encoding="utf-8", errors="replace"))
    return page


def broken_links(site: Path) -> Iterator[str]:
    """``page: href (why)`` for every internal link of the site at ``site`` that leads
    nowhere."""
    pages = {path.resolve(): _parse(path) for path in sorted(site.rglob("*.html"))}
    for path, page in pages.items():
        for href in page.links:
            parts = urllib.parse.urlsplit(href)
            if parts.scheme or parts.netloc or href.startswith(("mailto:", "javascript:")):
                continue  # external: not checked offline
            target = (path.parent / urllib.parse.unquote(parts.path)).resolve() \
                if parts.path else path
            where = f"{path.relative_to(site.resolve())}: {href}"
            if not target.exists():
                yield f"{where} (no such file)"
                continue
            if target.is_dir():
                target = target / "index.html"
                if not target.exists():
                    yield f"{where} (a directory without index.html)"
                    continue
            if parts.fragment and target.suffix == ".html":
                anchors = pages[target].anchors if target in pages else _parse(target).anchors
                if urllib.parse.unquote(parts.fragment) not in anchors:
                    yield f"{where} (no anchor #{parts.fragment})"


def main(argv: list[str]) -> int:
    """Check the site in ``argv[0]``; 0 if every internal link works, else 1."""
    if len(argv) != 1:
        print("usage: python tools/check_links.py SITE_DIR", file=sys.stderr)
        return 2
    site = Path(argv[0])
    if not (site / "index.html").exists():
        print(f"{site}: no index.html (build the site first)", file=sys.stderr)
        return 2
    broken = list(broken_links(site))
    for line in broken:
        print(line)
    pages = sum(1 for _ in site.rglob("*.html"))
    print(f"{len(broken)} broken internal link(s) in {pages} pages", file=sys.stderr)
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
