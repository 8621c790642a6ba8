"""Subprocesses of a test run "as if on Windows" run in that mode too (``aswindows.py``).

Python imports ``sitecustomize`` at start-up from ``sys.path``; ``tests/conftest.py``
puts this directory first on ``PYTHONPATH`` when ``TANGO_AIO_TEST_AS_WINDOWS=1``.
"""

from __future__ import annotations

import os

if os.environ.get("TANGO_AIO_TEST_AS_WINDOWS") == "1":
    import aswindows

    aswindows.install()
