"""Nothing in the package imports a POSIX-only module at the top level outside the pty
emulator and the POSIX fd transport (issue #27): on Windows such an import fails, and
with it every module that imports that one (``sim://`` once failed with "No module named
'fcntl'" because ``sim/inprocess.py`` imported ``sim/serve.py``)."""

from __future__ import annotations

import ast
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from aswindows import BLOCKED, environment

PACKAGE = Path(__file__).resolve().parents[2] / "tango_aio"
#: The modules that may: the pty emulator and the POSIX descriptor transport.
POSIX_MODULES = {"sim/ptyserve.py", "fdlink.py"}
#: Calls that exist on POSIX only.
POSIX_CALLS = {"os.openpty": {"sim/ptyserve.py"}, "os.ttyname": {"sim/ptyserve.py"}}


def _top_level(body: list[ast.stmt]) -> Iterator[ast.stmt]:
    """The statements that run when the module is imported: the module's body and the
    bodies of its top-level ``if``/``try``/``with`` blocks, not functions or classes, and
    not ``if TYPE_CHECKING:`` blocks."""
    for node in body:
        if isinstance(node, ast.If):
            if ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
                yield from _top_level(node.orelse)
                continue
            yield from _top_level(node.body)
            yield from _top_level(node.orelse)
        elif isinstance(node, ast.Try):
            for block in (node.body, node.orelse, node.finalbody,
                          *(handler.body for handler in node.handlers)):
                yield from _top_level(block)
        elif isinstance(node, ast.With):
            yield from _top_level(node.body)
        else:
            yield node


def _posix_imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in _top_level(tree.body):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            continue
        found += [f"line {node.lineno}: {name}" for name in names
                  if name.partition(".")[0] in BLOCKED]
    return found


def _modules() -> list[tuple[str, Path]]:
    return [(path.relative_to(PACKAGE).as_posix(), path)
            for path in sorted(PACKAGE.rglob("*.py"))]


def test_no_module_imports_a_posix_only_module_at_the_top_level() -> None:
    offenders = {name: found for name, path in _modules()
                 if name not in POSIX_MODULES and (found := _posix_imports(path))}
    assert offenders == {}


def test_the_check_sees_a_top_level_import(tmp_path: Path) -> None:
    module = tmp_path / "m.py"
    module.write_text("import os\ntry:\n    import fcntl\nexcept ImportError:\n    pass\n"
                      "if True:\n    from termios import tcgetattr\n"
                      "def f():\n    import tty\n", encoding="utf-8")
    assert _posix_imports(module) == ["line 3: fcntl", "line 7: termios"]
    assert _posix_imports(PACKAGE / "sim" / "ptyserve.py")  # it does: the check works


def test_posix_only_calls_stay_in_their_modules() -> None:
    for name, path in _modules():
        text = path.read_text(encoding="utf-8")
        for call, allowed in POSIX_CALLS.items():
            assert name in allowed or f"{call}(" not in text, f"{name} calls {call}"


def test_every_module_but_the_pty_emulator_imports_as_if_on_windows() -> None:
    """Each module imported in a fresh interpreter with the POSIX-only modules blocked
    (tests/windows_site): the import of the module and of all it imports succeeds."""
    names = [f"tango_aio.{name[:-3].replace('/', '.')}".removesuffix(".__init__")
             for name, _ in _modules() if name not in POSIX_MODULES and name != "__main__.py"]
    code = ("import importlib, sys\nfailed = []\n"
            f"for name in {names!r}:\n"
            "    try:\n        importlib.import_module(name)\n"
            "    except ImportError as exc:\n        failed.append(f'{name}: {exc}')\n"
            "print('\\n'.join(failed))\n"
            "import tango_aio.sim.ptyserve\n")  # the control: this one must fail
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                            timeout=120, check=False, env=environment())
    assert result.stdout.strip() == "", result.stdout
    assert "No module named 'fcntl'" in result.stderr, result.stderr
