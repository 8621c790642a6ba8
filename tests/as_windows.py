"""``TANGO_AIO_TEST_AS_WINDOWS=1`` runs the suite "as if on Windows" (issue #27).

Imported first by ``tests/conftest.py``: with the variable set, this installs the mode of
``tests/windows_site/aswindows.py`` in the test process before the helpers and the test
modules are imported, and puts that directory first on ``PYTHONPATH``, so that every
subprocess a test starts (the CLI, the examples, the README's code blocks) runs in the
same mode through ``tests/windows_site/sitecustomize.py``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["ACTIVE", "DIRECTORY"]

#: Where the mode's modules live (``aswindows.py``, ``sitecustomize.py``).
DIRECTORY = Path(__file__).resolve().parent / "windows_site"
#: Whether this run is "as if on Windows".
ACTIVE = os.environ.get("TANGO_AIO_TEST_AS_WINDOWS") == "1"

if str(DIRECTORY) not in sys.path:
    sys.path.insert(0, str(DIRECTORY))

if ACTIVE:
    import aswindows

    aswindows.install()
    os.environ.update(aswindows.environment())
