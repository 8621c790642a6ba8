"""Run this Python process "as if on Windows" (issue #27), on Linux.

:func:`install` makes what the project's own code (the package, the tests, the examples,
``python -c`` programs the tests start) sees look like Windows, where it differs in what
the package uses, and nothing else:

* ``fcntl``, ``termios``, ``tty``, ``pty`` and ``resource`` cannot be imported (a
  ``ModuleNotFoundError``, as on Windows), and ``os.openpty`` does not exist (an
  ``AttributeError``). Only imports made by the project's code are refused: pyserial,
  asyncio and pytest keep their POSIX internals, which they need to run here at all.
* The event loop's ``add_signal_handler``/``remove_signal_handler`` raise
  ``NotImplementedError``, as on Windows' loops (the base class does exactly that).
* ``tango_aio._platform.WINDOWS`` is true: it reads ``TANGO_AIO_TEST_AS_WINDOWS=1`` from
  the environment. ``sys.platform`` and ``os.name`` stay as they are (patching them
  globally breaks ``pathlib``, ``subprocess`` and pyserial in the test process): the
  package asks :mod:`tango_aio._platform` instead.

``tests/conftest.py`` calls :func:`install` when ``TANGO_AIO_TEST_AS_WINDOWS=1`` and puts
this directory first on ``PYTHONPATH``, so that every subprocess a test starts (the CLI,
the examples, the README's code blocks) runs in the same mode through
``sitecustomize.py`` here. What cannot be simulated: pyserial's Windows ``Serial``
(``serialwin32`` needs ``ctypes.windll``); the Windows transport runs on pyserial's POSIX
``Serial`` instead, which has the same blocking interface.
"""

from __future__ import annotations

import builtins
import os
import sys
from types import FrameType
from typing import Any, NoReturn

__all__ = ["BLOCKED", "ENV", "install", "installed"]

#: The environment variable that turns the mode on (tango_aio._platform reads it too).
ENV = "TANGO_AIO_TEST_AS_WINDOWS"
#: The POSIX-only modules Windows' Python does not have.
BLOCKED = frozenset({"fcntl", "termios", "tty", "pty", "resource"})

_HERE = os.path.dirname(os.path.abspath(__file__))
_ROOT = os.path.dirname(os.path.dirname(_HERE))
# Not benchmarks/: its pty benchmarks (scaling, watch) are POSIX-only tools, measured there.
_OURS = tuple(os.path.join(_ROOT, part) + os.sep
              for part in ("tango_aio", "tests", "examples", "docs"))
_installed = False


def installed() -> bool:
    """Whether :func:`install` ran in this process."""
    return _installed


def _ours(namespace: Any) -> bool:
    """Whether code with these globals is the project's own."""
    if not isinstance(namespace, dict):
        return False
    name = str(namespace.get("__name__") or "")
    if name == "tango_aio" or name.startswith("tango_aio."):
        return True
    path = namespace.get("__file__")
    if path is None:
        return name == "__main__"  # ``python -c`` and ``python -`` programs
    return os.path.abspath(str(path)).startswith(_OURS)


def _refuse_import(name: str) -> NoReturn:
    raise ModuleNotFoundError(f"No module named {name!r} (as on Windows: "
                              f"{ENV}=1)", name=name)


def install() -> None:
    """Turn the mode on in this process (idempotent)."""
    global _installed
    if _installed:
        return
    _installed = True
    original_import = builtins.__import__

    def guarded_import(name: str, globals: Any = None, locals: Any = None,
                       fromlist: Any = (), level: int = 0) -> Any:
        if level == 0 and name.partition(".")[0] in BLOCKED and _ours(globals):
            _refuse_import(name)
        return original_import(name, globals, locals, fromlist, level)

    def importing(name: str, globals: Any = None, locals: Any = None,
                  fromlist: Any = (), level: int = 0) -> Any:
        module = guarded_import(name, globals, locals, fromlist, level)
        if _loop_class() is not None:  # asyncio's loop is defined: patch it, once
            builtins.__import__ = guarded_import
            _no_signal_handlers()
        return module

    _hide_openpty()
    if _loop_class() is not None:
        builtins.__import__ = guarded_import
        _no_signal_handlers()
    else:  # asyncio not loaded yet: ``import tango_aio`` alone must not load it
        builtins.__import__ = importing


def _hide_openpty() -> None:
    original = os.openpty

    def openpty() -> tuple[int, int]:
        frame: FrameType | None = sys._getframe(1)
        if frame is not None and _ours(frame.f_globals):
            raise AttributeError(f"module 'os' has no attribute 'openpty' (as on Windows: "
                                 f"{ENV}=1)")
        return original()

    os.openpty = openpty


def _loop_class() -> Any:
    """asyncio's POSIX event loop class, once defined (asyncio may be half imported)."""
    return getattr(sys.modules.get("asyncio.unix_events"), "_UnixSelectorEventLoop", None)


def _no_signal_handlers() -> None:
    def add_signal_handler(self: Any, sig: int, callback: Any, *args: Any) -> NoReturn:
        raise NotImplementedError

    def remove_signal_handler(self: Any, sig: int) -> NoReturn:
        raise NotImplementedError

    loop_class = _loop_class()
    loop_class.add_signal_handler = add_signal_handler
    loop_class.remove_signal_handler = remove_signal_handler


def environment(base: dict[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: this process's environment) with the mode on for a subprocess:
    the variable set and this directory first on ``PYTHONPATH``."""
    env = dict(os.environ if base is None else base)
    env[ENV] = "1"
    paths = [p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p != _HERE]
    env["PYTHONPATH"] = os.pathsep.join([_HERE, *paths])
    return env
