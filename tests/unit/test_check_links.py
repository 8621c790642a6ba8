"""tools/check_links.py, the offline link check of the built documentation site (issue 30
item 9): it finds a link to a missing page and to a missing anchor, and follows nothing
external."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

from helpers import load_tool


def _tool() -> ModuleType:
    return load_tool("check_links")


def test_broken_files_and_anchors_are_found(tmp_path: Path) -> None:
    (tmp_path / "index.html").write_text(
        '<a href="api/a.html#ok">ok</a> <a href="api/a.html#gone">gone</a>'
        '<a href="missing.html">missing</a> <a href="https://example.org/x#y">ext</a>'
        '<a href="#top">self</a> <h1 id="top">t</h1> <img src="pic.svg">'
        '<a href="mailto:a@b">m</a>')
    (tmp_path / "api").mkdir()
    (tmp_path / "api" / "a.html").write_text('<dt id="ok">x</dt><a href="../index.html">b</a>')
    (tmp_path / "pic.svg").write_text("<svg/>")
    tool = _tool()
    assert sorted(tool.broken_links(tmp_path)) == [
        "index.html: api/a.html#gone (no anchor #gone)",
        "index.html: missing.html (no such file)"]
    assert tool.main([str(tmp_path)]) == 1
    (tmp_path / "index.html").write_text('<a href="api/a.html#ok">ok</a>')
    assert tool.main([str(tmp_path)]) == 0
    assert tool.main([str(tmp_path / "api")]) == 2  # not a site: no index.html
