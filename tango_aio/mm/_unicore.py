"""pymmcore-plus, imported so that the root logger keeps its level.

pymmcore-plus sets the root logger to DEBUG when it is imported (its
``configure_logging``): every library's debug records, the driver's wire trace among them,
would then be made and handed to the root's handlers. The caller's level is put back.
"""

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
