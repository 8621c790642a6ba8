"""The pages a reader sees: no code line that the docs theme clips, and an index that
lists its sections once."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WIDTH = 80  # furo's content column at 1280 px shows about this many code characters
QUICK_START_WIDTH = 88
_FENCE = re.compile(r"^[ \t]*(`{3,}|~{3,})[ \t]*(.*)$")
_SHOWN_DIRECTIVES = ("{code-block}", "{code}", "{sourcecode}")


def code_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) of every line inside a code block a reader sees.

    MyST directive fences (``{toctree}``, ``{eval-rst}``) are markup, not shown code;
    ``{code-block}`` is shown.
    """
    found: list[tuple[int, str]] = []
    fence = ""
    shown = False
    for number, line in enumerate(text.splitlines(), start=1):
        match = _FENCE.match(line)
        if not fence:
            if match:
                fence, info = match.group(1), match.group(2).strip()
                shown = not info.startswith("{") or info.startswith(_SHOWN_DIRECTIVES)
            continue
        if match and match.group(1)[0] == fence[0] and len(match.group(1)) >= len(fence) \
                and not match.group(2).strip():
            fence = ""
            continue
        if shown:
            found.append((number, line))
    return found


def pages() -> list[Path]:
    """The README and every Markdown page of the docs."""
    docs = [page for page in sorted((ROOT / "docs").rglob("*.md"))
            if "_build" not in page.parts]
    return [ROOT / "README.md", *docs]


def test_the_quick_start_lines_are_the_two_commands() -> None:
    readme = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    lines = sorted(quick_start_lines("\n".join(readme)))
    assert len(lines) == 2
    assert readme[lines[0] - 1].endswith("tango-aio demo")
    assert readme[lines[1] - 1].startswith("pip install -e '.[dev]'")


def test_the_parser_finds_code_and_skips_markup() -> None:
    text = "x\n````md\n```python\nshown\n```\n````\n```{toctree}\nhidden\n```\n" \
           "y\n  ~~~{code-block} sh\n  also\n  ~~~\nz\n"
    assert [line for _, line in code_lines(text)] == ["```python", "shown", "```", "  also"]


def quick_start_lines(readme: str) -> set[int]:
    """Line numbers of the README's Quick start commands (the block ``.ci/run`` runs)."""
    start = readme.index("\n## Quick start")
    first = readme.index("```sh\n", start)
    end = readme.index("```", first + 6)
    before = readme.count("\n", 0, first) + 1  # the fence's own line number
    return set(range(before + 1, before + 1 + readme.count("\n", first, end) - 1))


def test_no_code_line_is_wider_than_the_docs_column() -> None:
    wide = []
    for page in pages():
        text = page.read_text(encoding="utf-8")
        # .ci/run takes each Quick start command from one line, so those two may be as
        # long as the command is (the README is read on GitHub, not in the docs theme),
        # up to QUICK_START_WIDTH.
        exempt = quick_start_lines(text) if page.name == "README.md" else set()
        for number, line in code_lines(text):
            limit = QUICK_START_WIDTH if number in exempt else WIDTH
            if len(line) > limit:
                wide.append(f"{page.relative_to(ROOT)}:{number}: {len(line)} characters")
    assert not wide, "rewrap (a comment above the line, not beside it):\n" + "\n".join(wide)


def test_the_index_lists_its_sections_once() -> None:
    index = (ROOT / "docs" / "index.md").read_text(encoding="utf-8")
    captions = re.findall(r"^:caption: (.+)$", index, re.MULTILINE)
    assert {"Getting started", "Concepts", "How-to guides", "Reference"} <= set(captions)
    outside = "\n".join(part for number, part in
                        enumerate(re.split(r"^```.*$", index, flags=re.MULTILINE))
                        if number % 2 == 0)  # the text between code blocks
    for caption in captions:
        assert f"**{caption}**" not in outside, caption
        assert not re.search(rf"^[-*] .*{re.escape(caption)}", outside, re.MULTILINE), caption
