"""The README a new user reads first (issue 30 item 8): the Quick start installs the
small package to run the demo and the dev extra only to run the tests; extras are
installed in a way that works without PyPI; every Python fragment either runs as it stands
or says in one line that it runs inside ``async def main()``."""

from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text(encoding="utf-8")
_BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def quick_start() -> list[str]:
    """The lines of the first ```sh block after "## Quick start" (what .ci/run runs)."""
    section = README.split("## Quick start", 1)[1]
    block = section.split("```sh\n", 1)[1].split("```", 1)[0]
    return block.strip().splitlines()


def test_the_quick_start_runs_the_demo_without_the_dev_extra() -> None:
    first, second = quick_start()  # exactly two commands
    assert "pip install -e . " in first and "[dev]" not in first, first
    assert first.endswith("tango-aio demo"), first
    assert second.startswith("pip install -e '.[dev]' && ") and "pytest" in second, second


def test_extras_are_installed_from_the_checkout_not_from_pypi() -> None:
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    for page in pages:
        if "_build" in page.parts:
            continue
        text = page.read_text(encoding="utf-8")
        assert "pip install 'tango-aio[" not in text, page  # not on PyPI
    assert "pip install '/path/to/tango_aio[epics]'" in README


def _top_level_await(code: str) -> bool:
    try:
        compile(code, "<readme>", "exec")
    except SyntaxError:
        compile(code, "<readme>", "exec", flags=ast.PyCF_ALLOW_TOP_LEVEL_AWAIT)
        return True
    return False


def test_each_fragment_runs_as_it_stands_or_says_it_needs_async_def_main() -> None:
    fragments = list(_BLOCK.finditer(README))
    assert len(fragments) >= 8
    needing = 0
    for match in fragments:
        if not _top_level_await(match.group(1)):
            continue
        needing += 1
        before = README[: match.start()].rstrip().splitlines()
        lead = " ".join(before[-2:])  # the line (or two) right above the fence
        line = README[: match.start()].count("\n") + 1
        assert "inside `async def main()`" in lead, f"README.md:{line}: {lead!r}"
    assert needing >= 5  # Settings, Reconnect, Trigger lists, Many controllers, Events
