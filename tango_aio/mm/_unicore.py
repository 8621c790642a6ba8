"""pymmcore-plus, imported so that the root logger keeps its level."""

from __future__ import annotations

import logging

_root_level = logging.getLogger().level
try:
    import pymmcore_plus.experimental.unicore  # noqa: F401
except ImportError as exc:  # pragma: no cover - depends on the environment
    raise ImportError("tango_aio.mm needs pymmcore-plus: pip install 'tango-aio[mm]'"
                      ) from exc
finally:
    logging.getLogger().setLevel(_root_level)
