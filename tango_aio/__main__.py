"""``python -m tango_aio``: the same as the ``tango-aio`` command."""

import sys

from .cli import main

sys.exit(main())
