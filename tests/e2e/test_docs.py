"""The documentation site: every ``python`` code block runs against the emulator, and the
site builds with warnings as errors."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import forkrun
import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"
_BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def python_blocks() -> list[tuple[str, str]]:
    """(``page:n``, code) of every ```python block of the docs' Markdown pages."""
    blocks = []
    for page in sorted(DOCS.rglob("*.md")):
        if "_build" in page.parts:
            continue
        for number, match in enumerate(_BLOCK.finditer(page.read_text()), start=1):
            blocks.append((f"{page.relative_to(DOCS)}:{number}", match.group(1)))
    return blocks


BLOCKS = python_blocks()
#: The block that runs in a fresh interpreter (what a reader starts with).
FRESH = "getting-started.md:1"


def test_the_docs_have_code_blocks() -> None:
    assert len(BLOCKS) >= 10
    assert FRESH in dict(BLOCKS)


@pytest.mark.parametrize(("name", "code"), BLOCKS, ids=[name for name, _ in BLOCKS])
def test_python_block_runs(name: str, code: str, tmp_path: Path) -> None:
    """Each block is a complete program, run in a process of its own as a reader would:
    the first page's first block in a fresh interpreter, the others forked from one that
    has imported the package (``forkrun``)."""
    runner = subprocess.run if name == FRESH else forkrun.run
    result = runner([sys.executable, "-c", code], capture_output=True, text=True,
                    timeout=120, cwd=tmp_path, check=False)
    assert result.returncode == 0, f"{name}:\n{result.stdout}\n{result.stderr}"


@pytest.mark.slow
@pytest.mark.timeout(900)  # a hang's bound: the build takes minutes on a loaded machine
def test_the_docs_build_without_warnings(tmp_path: Path) -> None:
    pytest.importorskip("sphinx")
    pytest.importorskip("myst_parser")
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
         "-d", str(tmp_path / "doctrees"), str(DOCS), str(tmp_path / "html")],
        capture_output=True, text=True, timeout=600, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    html = tmp_path / "html"
    errors = (html / "reference" / "errors.html").read_text()
    assert "OutOfRangeError" in errors and "LimitSwitchActiveError" in errors
    assert "tango-aio upload-trigp" in (html / "reference" / "cli.html").read_text()
    page = html / "reference" / "api" / "tango_aio.html"
    assert "move_to" in page.read_text()
    # No broken internal link or anchor (viewcode's back-links, its module index).
    check = subprocess.run([sys.executable, str(ROOT / "tools" / "check_links.py"),
                            str(html)], capture_output=True, text=True, check=False)
    assert check.returncode == 0, check.stdout + check.stderr
    # A theme made for API references, with an on-page contents; the public API only.
    controller = page.read_text()
    assert "furo" in controller and "On this page" in controller
    assert 'id="tango_aio.Controller"' in controller
    documented = {path.name for path in (html / "reference" / "api").glob("*.html")}
    assert "tango_aio.sync.html" in documented and "tango_aio.families.html" in documented
    assert not [name for name in documented if "._" in name], documented
    # The pictures, drawn from a run of the emulator at build time.
    replies = (html / "concepts" / "replies.html").read_text()
    assert "<svg" in replies and "reply to sa" in replies
    raster = (html / "howto" / "raster-scan.html").read_text()
    assert raster.count("class='pulse'") == 27
