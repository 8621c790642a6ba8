"""The ``tango-aio`` command line: results on stdout, diagnostics on stderr, exit 0/1/2/130."""

from __future__ import annotations

from ._main import (
    main,
)

__all__ = [
    "main",
]
