"""Reply-line rules of the reads whose reply length is not one line."""

from __future__ import annotations

import re
from typing import Final

from ._schema import Command, Context, LineRule

__all__ = ["detext_lines", "grouped_lines", "mrt_lines", "service_lines"]


def service_lines(command: Command, context: Context) -> LineRule:
    """``?service``: from firmware 1.60C/1.61 the last line is ``END_SERVICE_PRINT.``
    (L2937-2943)."""
    return LineRule(count=0, terminator="END_SERVICE_PRINT.")


_DETEXT_MORE: Final = re.compile(r"^=")


def detext_lines(command: Command, context: Context) -> LineRule:
    """``?detext``: the hex configuration, then one ``= feature`` line each; no end marker
    (L1189-1220)."""
    return LineRule(count=1, continuation=_DETEXT_MORE)


def mrt_lines(command: Command, context: Context) -> LineRule:
    """``?mrt n``: one line per sample, 10 by default; a negative count means the same
    number (L11474)."""
    samples = abs(int(command.values[0])) if command.values else 10
    return LineRule(count=samples)


_GROUP_MORE: Final = re.compile(r"^[-+\d.,]+[ ,][-+\d., ]*$")


def grouped_lines(command: Command, context: Context) -> LineRule:
    """``?lim`` and ``?swtyp`` without an axis print an extra CR between axes in extmode 0
    (L4559-4619, L4818-4822): read until the next request's reply."""
    if command.axis is not None or context.extmode != 0 or context.axes < 2:
        return LineRule()
    return LineRule(count=1, continuation=_GROUP_MORE)
