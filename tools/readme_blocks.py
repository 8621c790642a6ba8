"""Run the README's complete ``python`` code blocks, each in a fresh interpreter.

A block is complete when it compiles as a program (fragments with a top-level ``await``
do not) and names no real device outside its comments (``/dev/...``, ``COM3``); the others are
shown in the README as parts of a program. The ``tango_emulator`` test block is run as a
test module by ``tests/e2e/test_testing.py``. CI runs this "as if on Windows"
(``TANGO_AIO_TEST_AS_WINDOWS=1``, issue #27): the subprocesses inherit the environment.

Usage: ``python tools/readme_blocks.py [README.md]``; exit status 1 if a block fails.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

_BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
_DEVICE = re.compile(r"""["'](/dev/|COM\d)""")


def complete_blocks(text: str) -> list[tuple[int, str]]:
    """(line number, code) of each complete block of ``text``."""
    found = []
    for match in _BLOCK.finditer(text):
        code = match.group(1)
        line = text.count("\n", 0, match.start()) + 1
        try:
            compile(code, f"README.md:{line}", "exec")
        except SyntaxError:
            continue
        uncommented = "\n".join(row.split("#", 1)[0] for row in code.splitlines())
        if _DEVICE.search(uncommented) or "def test_" in code:
            continue
        found.append((line, code))
    return found


def main(argv: list[str]) -> int:
    """Run each complete block; print one line per block; 1 if any failed."""
    readme = Path(argv[0] if argv else Path(__file__).resolve().parents[1] / "README.md")
    blocks = complete_blocks(readme.read_text(encoding="utf-8"))
    if not blocks:
        print("no complete python blocks found", file=sys.stderr)
        return 1
    failed = 0
    for line, code in blocks:
        result = subprocess.run([sys.executable, "-c", code], capture_output=True,
                                text=True, timeout=300, check=False)
        status = "ok" if result.returncode == 0 else f"FAILED ({result.returncode})"
        print(f"README.md:{line}: {status}", flush=True)
        if result.returncode != 0:
            failed += 1
            print(result.stdout + result.stderr, file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
