"""The one place the package asks which platform it runs on (issue #27).

Windows lacks what the POSIX code paths use: ptys (``os.openpty``), ``termios``, ``tty``,
``fcntl`` (the ``flock`` port lock), ``resource``, ``signal.pthread_sigmask``, and an event
loop with ``add_signal_handler``. Code that branches on the platform asks
:data:`WINDOWS` here rather than ``sys.platform`` or ``os.name`` itself, so that the test
suite can run the Windows branches on Linux: ``TANGO_AIO_TEST_AS_WINDOWS=1`` makes
:data:`WINDOWS` true (together with the import blocker of ``tests/windows_site``, which makes
the POSIX-only modules unimportable as they are on Windows; see ``tests/README.md``).
"""

from __future__ import annotations

import os
import sys

__all__ = ["AS_WINDOWS_ENV", "POSIX", "WINDOWS"]

#: The environment variable that makes the package take its Windows paths (tests only).
AS_WINDOWS_ENV = "TANGO_AIO_TEST_AS_WINDOWS"

#: True on Windows, or when the test suite runs "as if on Windows".
WINDOWS: bool = sys.platform == "win32" or os.environ.get(AS_WINDOWS_ENV) == "1"

#: True where the POSIX paths are taken (Linux, macOS, the BSDs): ptys, termios, the
#: descriptor transport, ``flock``, ``add_signal_handler``.
POSIX: bool = os.name == "posix" and not WINDOWS
