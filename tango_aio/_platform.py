"""The one place the package asks which platform it runs on."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator

__all__ = ["AS_WINDOWS_ENV", "POSIX", "WINDOWS", "signal_calls"]

#: The environment variable that makes the package take its Windows paths (tests only).
AS_WINDOWS_ENV = "TANGO_AIO_TEST_AS_WINDOWS"

#: True on Windows, or when the test suite runs "as if on Windows".
WINDOWS: bool = sys.platform == "win32" or os.environ.get(AS_WINDOWS_ENV) == "1"

#: True where the POSIX paths are taken (Linux, macOS, the BSDs): ptys, termios, the
#: descriptor transport, ``flock``, ``add_signal_handler``.
POSIX: bool = os.name == "posix" and not WINDOWS


@contextlib.contextmanager
def signal_calls(sig: int, callback: Callable[[], None]) -> Iterator[bool]:
    """Run ``callback`` on the running loop when ``sig`` arrives, for the block; yields
    whether a handler is installed."""
    loop = asyncio.get_running_loop()
    previous = signal.getsignal(sig)
    try:
        loop.add_signal_handler(sig, callback)
    except NotImplementedError:
        fallback = True
        installed = threading.current_thread() is threading.main_thread()
    except (RuntimeError, ValueError):  # not the main thread, or no such signal
        fallback = installed = False
    else:
        fallback, installed = False, True
    if installed and fallback:

        def handler(signum: int, frame: object) -> None:
            with contextlib.suppress(RuntimeError):  # the loop is already closed
                loop.call_soon_threadsafe(callback)

        signal.signal(sig, handler)
    try:
        yield installed
    finally:
        if installed and not fallback:
            loop.remove_signal_handler(sig)
        if installed:
            signal.signal(sig, previous)
