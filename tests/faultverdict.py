"""Verdicts of the fault matrix and the soak (tests/e2e/test_fault_matrix.py): what one
call's outcome means, judged against the emulator's own state. Pure functions, tested in
tests/unit/test_faultverdict.py.

A verdict is a short text; those in :data:`BAD` break the first rule (a reply handed to
the wrong caller, a success the controller does not bear out, an axis left running that
the error does not name, a hang, an error outside :class:`TangoError`). A typed error is
``"error <class>"``: allowed, and counted by class.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Iterable

from tango_aio.errors import MoveOutcomeUnknown, TangoError

OWN = "own"
#: One character of the caller's own reply differs: a one-bit error, which a link without
#: checksums cannot show (allowed only where the fault flips a bit).
GARBLED_OWN = "garbled own"
#: A set, move, speed or upload returned, and the emulator holds what it claimed.
DONE = "done"
MISDELIVERED = "MISDELIVERED"
#: A read returned a value that is neither its own nor anyone's (e.g. noise glued on).
WRONG_VALUE = "WRONG VALUE"
FALSE_SUCCESS = "FALSE SUCCESS"
UNSTOPPED = "UNSTOPPED"
UNTYPED = "UNTYPED ERROR"
HANG = "HANG"
#: The call after the faulted one (the same operation, no fault) did not work.
NEXT_CALL_FAILED = "NEXT CALL FAILED"

#: The verdicts that break the first rule.
BAD = frozenset({MISDELIVERED, WRONG_VALUE, FALSE_SUCCESS, UNSTOPPED, UNTYPED, HANG,
                 NEXT_CALL_FAILED})

#: What an error's text says of the axes it left running (``axes X Z may still move``).
_MAY_MOVE = re.compile(r"\baxes? ([A-Z](?: [A-Z])*) may still move")


class Hang(Exception):
    """A call gave no result within the matrix's hang bound."""


def error_verdict(exc: BaseException) -> str:
    """``error <class>`` for a :class:`TangoError`, :data:`HANG` for :class:`Hang`,
    :data:`UNTYPED` for anything else."""
    if isinstance(exc, Hang):
        return HANG
    if isinstance(exc, TangoError):
        return f"error {type(exc).__name__}"
    return UNTYPED


def one_char_apart(a: str, b: str) -> bool:
    """Same length, exactly one character different."""
    return len(a) == len(b) and sum(x != y for x, y in zip(a, b, strict=True)) == 1


def read_verdict(result: object, own: str, others: Collection[str], *,
                 bit_flips: bool = False) -> str:
    """The verdict on a read that returned ``result`` (a text or an exception), whose
    own reply is ``own`` and whose look-alikes answer ``others`` (the emulator's store at
    that moment). ``bit_flips``: the fault flips a bit, so one character off its own
    reply is :data:`GARBLED_OWN` rather than :data:`WRONG_VALUE`."""
    if isinstance(result, BaseException):
        return error_verdict(result)
    if result == own:
        return OWN
    if result in others:
        return MISDELIVERED
    if bit_flips and isinstance(result, str) and one_char_apart(result, own):
        return GARBLED_OWN
    return WRONG_VALUE


def done_verdict(result: object, held: bool) -> str:
    """The verdict on a set, move, speed or upload: it returned (``result`` is no
    exception) and the emulator ``held`` what it claims (the value, the target, the
    running axis, the list), or it raised."""
    if isinstance(result, BaseException):
        return error_verdict(result)
    return DONE if held else FALSE_SUCCESS


def names_axis(exc: BaseException, axis: str) -> bool:
    """``exc`` says that ``axis`` may still move: a :class:`MoveOutcomeUnknown` (naming
    it, when it names axes at all), or an error whose text or notes say ``may still
    move`` with the axis' letter."""
    if isinstance(exc, MoveOutcomeUnknown):
        axes = getattr(exc, "axes", None)
        return axes is None or axis in axes
    text = " ".join([str(exc), *getattr(exc, "__notes__", ())])
    return any(axis.upper() in named.split() for named in _MAY_MOVE.findall(text))


def running_verdict(result: object, ran_on: Iterable[str]) -> str | None:
    """:data:`UNSTOPPED` when a call that raised left axes running (``ran_on``: axes it
    started that still ran, in the emulator, after it raised) that its error does not
    name; ``None`` otherwise (a call that returned is judged by :func:`done_verdict`)."""
    if not isinstance(result, BaseException):
        return None
    if any(not names_axis(result, axis) for axis in ran_on):
        return UNSTOPPED
    return None


def is_bad(verdict: str) -> bool:
    """The verdict breaks the first rule."""
    return verdict.split(":")[0] in BAD
