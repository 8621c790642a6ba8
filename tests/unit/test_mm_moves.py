"""tango_aio.mm's record of started moves: busy until each has ended, a failure handed
to the next call once, a move stopped on purpose no failure."""

from __future__ import annotations

import concurrent.futures
from typing import Any

import pytest

pytest.importorskip("tango_aio.mm")  # first: it keeps the root logger's level

from tango_aio import MoveError
from tango_aio.mm._moves import Moves


def started(moves: Moves) -> concurrent.futures.Future[Any]:
    future: concurrent.futures.Future[Any] = concurrent.futures.Future()
    future.set_running_or_notify_cancel()
    moves.add(future)
    return future


def test_busy_until_every_move_has_its_verdict() -> None:
    moves = Moves()
    assert not moves.busy()
    first, second = started(moves), started(moves)
    assert moves.busy()
    first.set_result({"x": "@"})
    assert moves.busy()
    second.set_result({"y": "@"})
    assert not moves.busy()


def test_a_failure_is_raised_once_by_the_next_call() -> None:
    moves = Moves()
    move = started(moves)
    error = MoveError("X stopped at its upper limit switch (EE) (status S)", {"x": "S"})
    move.set_exception(error)
    with pytest.raises(MoveError) as raised:
        moves.busy()
    assert raised.value is error
    moves.check()  # handed over: the next call goes on
    assert not moves.busy()


def test_the_first_started_of_two_failures_is_the_one_raised() -> None:
    moves = Moves()
    first, second = started(moves), started(moves)
    second.set_exception(MoveError("second", {"y": "S"}))
    first.set_exception(MoveError("first", {"x": "S"}))
    with pytest.raises(MoveError, match="first"):
        moves.check()
    moves.check()  # the other is not raised later as if it were news


def test_a_move_stopped_on_purpose_is_no_failure() -> None:
    moves = Moves()
    move = started(moves)
    assert moves.stopping() == [move]
    move.set_exception(MoveError("X was stopped", {"x": "@"}))
    assert not moves.busy()
    moves.check()
    cancelled: concurrent.futures.Future[Any] = concurrent.futures.Future()
    moves.add(cancelled)
    assert moves.busy()
    assert cancelled.cancel()  # e.g. a move whose line was never written
    assert not moves.busy()


def test_the_end_of_moves_is_told_once() -> None:
    moves = Moves()
    assert not moves.ended()
    first, second = started(moves), started(moves)
    assert not moves.ended()
    first.set_result({})
    second.set_exception(MoveError("short", {"x": "S"}))
    assert moves.ended() and not moves.ended()
    with pytest.raises(MoveError):
        moves.check()
