"""The fault matrix's verdicts (tests/faultverdict.py): what an outcome means."""

from __future__ import annotations

import pytest
from faultverdict import (
    DONE,
    FALSE_SUCCESS,
    GARBLED_OWN,
    HANG,
    MISDELIVERED,
    NEXT_CALL_FAILED,
    OWN,
    UNSTOPPED,
    UNTYPED,
    WRONG_VALUE,
    Hang,
    done_verdict,
    error_verdict,
    is_bad,
    names_axis,
    read_verdict,
    running_verdict,
)

from tango_aio.controller._motion import annotate
from tango_aio.errors import (
    ControllerTimeoutError,
    MoveProtocolUnknownError,
    NotExecutableError,
    ProtocolError,
)

OTHERS = ("96.250", "97.125", "18.500")


@pytest.mark.parametrize(("result", "bit_flips", "verdict"), [
    ("95.500", False, OWN),
    ("96.250", False, MISDELIVERED),  # another read's value
    ("96.250", True, MISDELIVERED),  # even where bits flip: it is someone's
    ("95.700", True, GARBLED_OWN),  # one character off, the fault flips bits
    ("95.700", False, WRONG_VALUE),  # the same without bit flips
    ("195.500", True, WRONG_VALUE),  # noise glued on: longer
    ("88.875", False, WRONG_VALUE),  # an extra line taken for the reply
    (ProtocolError("no number"), False, "error ProtocolError"),
    (ControllerTimeoutError("late"), True, "error ControllerTimeoutError"),
    (ValueError("could not convert"), False, UNTYPED),
    (Hang("no result"), False, HANG),
])
def test_read_verdict(result: object, bit_flips: bool, verdict: str) -> None:
    assert read_verdict(result, "95.500", OTHERS, bit_flips=bit_flips) == verdict


def test_done_verdict() -> None:
    assert done_verdict(None, held=True) == DONE
    assert done_verdict({"x": "@"}, held=True) == DONE
    assert done_verdict(None, held=False) == FALSE_SUCCESS
    assert done_verdict(NotExecutableError(command="!moa 1"), held=False) == \
        "error NotExecutableError"
    assert done_verdict(RuntimeError("bug"), held=True) == UNTYPED


def test_error_verdict_tells_a_hang_from_a_timeout() -> None:
    assert error_verdict(Hang("60 s")) == HANG
    assert error_verdict(ControllerTimeoutError("0.3 s")) == "error ControllerTimeoutError"
    assert error_verdict(TimeoutError()) == UNTYPED


def test_running_verdict() -> None:
    refused = NotExecutableError(command="!speed z 2")
    assert running_verdict(refused, []) is None
    assert running_verdict(refused, ["x"]) == UNSTOPPED  # "refused" while X ran on
    assert running_verdict(None, ["x"]) is None  # a call that returned: done_verdict
    # A MoveOutcomeUnknown says the stage may have moved: allowed, for the axes it
    # names when it names any.
    unknown = MoveProtocolUnknownError("garbled")
    assert running_verdict(unknown, ["x", "y"]) is None
    unknown.axes = ("x",)  # type: ignore[attr-defined]
    assert running_verdict(unknown, ["x"]) is None
    assert running_verdict(unknown, ["x", "y"]) == UNSTOPPED


def test_an_error_that_says_the_axes_may_still_move_names_them() -> None:
    lost = annotate(ControllerTimeoutError("no reply to '!speed z 2'"),
                    "axes Z X may still move")
    assert names_axis(lost, "z") and names_axis(lost, "x")
    assert not names_axis(lost, "y")
    assert running_verdict(lost, ["z"]) is None
    stopped = annotate(ControllerTimeoutError("no reply"), "axes Z stopped")
    assert running_verdict(stopped, ["z"]) == UNSTOPPED
    noted = annotate(ControllerTimeoutError(), "axes Y may still move")  # no text: a note
    assert names_axis(noted, "y")


@pytest.mark.parametrize("verdict", [MISDELIVERED, WRONG_VALUE, FALSE_SUCCESS, UNSTOPPED,
                                     UNTYPED, HANG, NEXT_CALL_FAILED])
def test_bad_verdicts(verdict: str) -> None:
    assert is_bad(verdict)


@pytest.mark.parametrize("verdict", [OWN, GARBLED_OWN, DONE, "error ProtocolError",
                                     "error MoveTimeoutUnknownError"])
def test_allowed_verdicts(verdict: str) -> None:
    assert not is_bad(verdict)
