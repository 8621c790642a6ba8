"""Every numeric reply the shape check lets through is a number ``float()`` parses.

A garbled reply that still passes the check reaches the code that converts it: a bit
flipped in ``?pos``'s ``0.0000`` gives ``0,0000``, which ``float()`` refuses. The only
commas the controller prints end a value (``?lim`` in extmode 0: ``-2600 2600,``,
manual L4619), so a comma inside a token is no number.
"""

from __future__ import annotations

import contextlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tango_aio.catalog._instructions import INSTRUCTIONS, Context, LineRule, parse
from tango_aio.catalog._replies import parse_reply, reply_rule
from tango_aio.errors import ProtocolError
from tango_aio.sansio._patterns import ReplyKind, reply_pattern

CONTEXT = Context(axes=3)


def _numeric_reads() -> list[str]:
    """Every read of the catalog (bare, and with an axis) answered by one line of
    numbers."""
    lines = []
    for name, entry in sorted(INSTRUCTIONS.items()):
        if not entry.read:
            continue
        for text in (f"?{name}", f"?{name} x"):
            try:
                command = parse(text, CONTEXT)
            except ValueError:
                continue
            if reply_rule(command, CONTEXT) == LineRule(count=1) and \
                    reply_pattern(command, CONTEXT).kind is ReplyKind.NUMBERS:
                lines.append(command.line)
    return lines


NUMERIC_READS = _numeric_reads()


def test_the_catalog_has_numeric_reads() -> None:
    assert {"?pos", "?pos x", "?vel x", "?err", "?lim x"} <= set(NUMERIC_READS)


@settings(max_examples=400)
@given(read=st.sampled_from(NUMERIC_READS),
       line=st.text(alphabet="0123456789.,-+eE ", min_size=1, max_size=24))
def test_an_accepted_numeric_reply_parses(read: str, line: str) -> None:
    command = parse(read, CONTEXT)
    if not reply_pattern(command, CONTEXT).accepts(line):
        return
    for token in line.split():
        float(token.removesuffix(","))
    # A number of the wrong kind (a fraction for an integer) is a typed error.
    with contextlib.suppress(ProtocolError):
        parse_reply(command, [line])


@pytest.mark.parametrize("line", ["0,0000 0.0000 0.0000", "1.5 2,5", "0,5", "1.0,2.0",
                                  ",", "1 , 2"])
def test_a_comma_inside_or_alone_is_refused(line: str) -> None:
    assert not reply_pattern(parse("?pos", CONTEXT), CONTEXT).accepts(line)


@pytest.mark.parametrize("line", ["-2600 2600,", "-2600 2600, "])
def test_a_comma_that_ends_a_value_is_accepted(line: str) -> None:
    lim = parse("?lim x", CONTEXT)
    assert reply_pattern(lim, CONTEXT).accepts(line)
    assert parse_reply(lim, [line]) == (-2600.0, 2600.0)
