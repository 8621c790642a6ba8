"""The README a new user reads first (issue 30 item 8, issue 44): the Quick start installs
the small package to run the demo and the dev extra only to run the tests; extras are
installed in a way that works without PyPI; one complete example per surface; its links
lead into the docs."""

from __future__ import annotations

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


def test_each_python_block_is_a_complete_program() -> None:
    """Each example runs as it stands (``tools/readme_blocks.py`` runs them in CI): no
    fragment that needs an ``async def main()`` around it."""
    fragments = list(_BLOCK.finditer(README))
    assert len(fragments) >= 4  # asyncio, blocking, Bluesky, the pytest plugin
    for match in fragments:
        line = README[: match.start()].count("\n") + 1
        compile(match.group(1), f"README.md:{line}", "exec")  # no top-level await


def test_the_examples_cover_every_surface() -> None:
    examples = README.split("## Examples", 1)[1].split("\n## ", 1)[0]
    for needle in ("asyncio.run(", "tango_aio.sync", "tango-aio ", "MarzhauserStage",
                   "tango-aio ioc", "tango_emulator"):
        assert needle in examples, needle


def test_every_relative_link_leads_to_a_file() -> None:
    targets = re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", README)
    assert len(targets) >= 15
    for target in targets:
        assert (ROOT / target).exists(), target
