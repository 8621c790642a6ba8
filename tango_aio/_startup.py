"""Ctrl+C while the command line starts ends quietly."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from types import FrameType

__all__ = ["finished", "install"]


def _interrupted(signum: int, frame: FrameType | None) -> None:
    # Not ``raise SystemExit``: a signal handler runs between any two bytecodes, also
    # inside the import machinery's weakref callbacks, where Python prints the exception
    # as "Exception ignored in ..." with its traceback and carries on loading. Nothing is
    # open yet while modules load (no port, no task), so leaving at once loses nothing.
    with contextlib.suppress(Exception):
        sys.stdout.flush()
        sys.stderr.write("interrupted\n")
        sys.stderr.flush()
    os._exit(130)


_installed = False


def install() -> bool:
    """This process is the command: from now until :func:`finished`, Ctrl+C exits quietly
    with 130. Only the command's own start calls it, never an import: a program or a test
    process that merely imports :mod:`tango_aio.cli` keeps its own Ctrl+C. Returns whether
    it was installed (not outside the main thread, nor over someone else's handler)."""
    global _installed
    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return False
    signal.signal(signal.SIGINT, _interrupted)
    _installed = True
    return True


def finished() -> None:
    """Start-up is over: Ctrl+C raises ``KeyboardInterrupt`` again."""
    global _installed
    if _installed and signal.getsignal(signal.SIGINT) is _interrupted:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    _installed = False
