"""``python -m tango_aio``: the same as the ``tango-aio`` command."""

import sys

from . import _startup

_startup.install()  # before the command line loads: Ctrl+C while it loads exits quietly

from .cli import main  # noqa: E402

sys.exit(main())
