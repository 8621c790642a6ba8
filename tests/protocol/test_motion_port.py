""":class:`tango_aio.controller._motion.Motion` through its six-intent port alone: a fake port, no
link, no controller. Each test records the intents a move used, in order."""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import pytest
from helpers import true_within_ticks

from tango_aio.catalog._instructions import Command, parse
from tango_aio.controller._motion import Motion, MotionPort, MovePlan
from tango_aio.errors import (
    ControllerError,
    LimitSwitchActiveError,
    MoveError,
    MoveProtocolUnknownError,
)
from tango_aio.events import MoveFinished
from tango_aio.link._protocol import MoveHandle
from tango_aio.moves._timing import Budget
from tango_aio.sansio._core import Completed


@dataclass(eq=False)
class _Submission:
    command: Command
    completion: asyncio.Future[Any] | None = None


@dataclass
class _Handle:
    submission: _Submission
    forgotten: int = 0

    def forget(self) -> None:
        self.forgotten += 1


@dataclass
class _Port:
    """Answers each intent from a script and records it."""

    reads: list[tuple[dict[str, str], dict[str, str]]]
    refusal: ControllerError | None = None
    calls: list[str] = field(default_factory=list)
    finished_events: list[MoveFinished] = field(default_factory=list)
    #: The move's completion report, when the test gives it one (owed or come).
    report: asyncio.Future[Any] | None = None

    def start(self, command: Command, batch: object | None) -> MoveHandle:
        self.calls.append(f"start {command.line}")
        return cast(MoveHandle, _Handle(_Submission(command, self.report)))

    async def accepted(self, sent: MoveHandle) -> ControllerError | None:
        self.calls.append("accepted")
        return self.refusal

    async def stop(self) -> None:
        self.calls.append("stop")

    async def read_state(self, axes: Sequence[str]
                         ) -> tuple[dict[str, str], dict[str, str]]:
        self.calls.append(f"read_state {''.join(axes)}")
        return self.reads.pop(0)

    def finished(self, event: MoveFinished) -> None:
        self.calls.append("finished")
        self.finished_events.append(event)

    def unreported(self) -> None:
        self.calls.append("unreported")


def _planner(targets: Mapping[str, float]) -> Any:
    async def plan(command: Command, known: Mapping[str, str] | None) -> MovePlan:
        assert known is None  # nothing read yet
        return MovePlan(command, ("x",), targets,
                        Budget(delay=0.0, travel=0.0, after=0.0, settle=0.0, limit=5.0))
    return plan


async def test_a_move_that_arrives_uses_start_accepted_read_state_finished() -> None:
    port = _Port(reads=[({"x": "@", "y": "@"}, {"x": "10.000"})])
    motion = Motion(cast(MotionPort, port))
    letters = await motion.run(parse("!moa x 10"), _planner({"x": 10.0}), True)
    assert letters == {"x": "@", "y": "@"}
    assert port.calls == ["start !moa x 10", "accepted", "read_state x", "finished"]
    [event] = port.finished_events
    assert (event.kind, event.statuses, event.ok) == ("move", {"x": "@", "y": "@"}, True)
    assert motion.positions == {"x": "10.000"}


async def test_a_move_at_a_limit_switch_fails_with_its_words_after_one_read() -> None:
    port = _Port(reads=[({"x": "S"}, {"x": "5.000"})])
    motion = Motion(cast(MotionPort, port))
    with pytest.raises(MoveError, match="X stopped at its upper limit switch"):
        await motion.run(parse("!moa x 10"), _planner({"x": 10.0}), True)
    assert port.calls == ["start !moa x 10", "accepted", "read_state x", "finished"]
    assert port.finished_events[0].ok is False


async def test_a_refused_line_is_raised_after_one_read_that_shows_nothing_moving() -> None:
    """A flipped bit makes a documented refusal of an ``?err`` that said 0: the refusal
    stands once the state read behind it shows X standing where it stood."""
    port = _Port(reads=[({"x": "@"}, {"x": "0.000"})],
                 refusal=LimitSwitchActiveError(command="!moa x 10"))
    motion = Motion(cast(MotionPort, port))
    with pytest.raises(LimitSwitchActiveError):
        await motion.run(parse("!moa x 10"), _planner({"x": 10.0}), True)
    assert port.calls == ["start !moa x 10", "accepted", "read_state x"]


async def test_a_refusal_that_motion_contradicts_stops_the_axes_and_says_so() -> None:
    port = _Port(reads=[({"x": "M"}, {"x": "0.500"}), ({"x": "E"}, {"x": "0.600"})],
                 refusal=LimitSwitchActiveError(command="!moa x 10"))
    motion = Motion(cast(MotionPort, port))
    with pytest.raises(MoveProtocolUnknownError, match=r"X moving.*axes X stopped"):
        await motion.run(parse("!moa x 10"), _planner({"x": 10.0}), True)
    assert port.calls == ["start !moa x 10", "accepted", "read_state x", "stop",
                          "read_state x"]


class _WritingPort(_Port):
    """Writes a read when it is asked for (``write``), reads it when awaited (``read``),
    as the controller does."""

    def read_state(self, axes: Sequence[str]
                   ) -> Coroutine[Any, Any, tuple[dict[str, str], dict[str, str]]]:
        self.calls.append(f"write {''.join(axes)}")

        async def read() -> tuple[dict[str, str], dict[str, str]]:
            self.calls.append("read")
            return self.reads.pop(0)

        return read()


async def _waiting_for_a_hint(port: _Port, motion: Motion) -> asyncio.Task[dict[str, str]]:
    async def plan(command: Command, known: Mapping[str, str] | None) -> MovePlan:
        return MovePlan(command, ("x",), {"x": 10.0},
                        Budget(delay=0.0, travel=60.0, after=0.0, settle=0.0, limit=120.0))

    task = asyncio.create_task(motion.run(parse("!moa x 10"), plan, True))
    await true_within_ticks(lambda: port.calls == ["start !moa x 10", "accepted"])
    for _ in range(3):
        await asyncio.sleep(0)  # into the wait for a hint
    return task


async def test_a_report_writes_the_read_and_a_cancel_drops_it_and_stops() -> None:
    """#28: a report while the move waits for one writes the read at once
    (:meth:`Motion.reported`); a cancel that comes before the move's task ran again
    drops that read unstarted and stops the axes, whose stop is then confirmed by a read
    of its own."""
    port = _WritingPort(reads=[({"x": "@"}, {"x": "3.000"})])
    motion = Motion(cast(MotionPort, port))
    task = await _waiting_for_a_hint(port, motion)
    motion.reported()
    assert port.calls[-1] == "write x"  # in the report's turn
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert port.calls == ["start !moa x 10", "accepted", "write x", "stop", "accepted",
                          "write x", "read"]


async def test_a_report_read_is_the_moves_confirmation() -> None:
    """The read :meth:`Motion.reported` writes is the one the move is confirmed with: no
    second read after the wake."""
    port = _WritingPort(reads=[({"x": "@"}, {"x": "10.000"})])
    motion = Motion(cast(MotionPort, port))
    task = await _waiting_for_a_hint(port, motion)
    motion.reported()
    assert await task == {"x": "@"}
    assert port.calls == ["start !moa x 10", "accepted", "write x", "read", "finished"]


@pytest.mark.parametrize("reported", [False, True])
async def test_a_move_that_stopped_short_without_its_report_says_so(reported: bool) -> None:
    """A restart loses the move and its report: a move found standing short with its
    report still owed tells the port (which reads the mode), one whose report came not."""
    port = _Port(reads=[({"x": "@"}, {"x": "0.000"})])
    port.report = asyncio.get_running_loop().create_future()
    if reported:
        port.report.set_result(Completed(None, {"x": "@", "y": "@"}, "@@"))
    motion = Motion(cast(MotionPort, port))
    with pytest.raises(MoveError, match="X stopped short"):
        await motion.run(parse("!moa x 10"), _planner({"x": 10.0}), True)
    assert ("unreported" in port.calls) is not reported


async def test_an_axis_that_stood_short_of_its_target_reads_as_failed_in_the_error() -> None:
    """A merged move's error names, per axis, whether it ended well: an axis that stands
    short of its target with ``@`` reads ``E`` in ``statuses`` (the IOC judges its axis
    by that letter), the one that arrived keeps its ``@``."""
    port = _Port(reads=[({"x": "@", "y": "@"}, {"x": "4.000", "y": "2.000"})])
    motion = Motion(cast(MotionPort, port))

    async def plan(command: Command, known: Mapping[str, str] | None) -> MovePlan:
        return MovePlan(command, ("x", "y"), {"x": 10.0, "y": 2.0},
                        Budget(delay=0.0, travel=0.0, after=0.0, settle=0.0, limit=5.0))

    with pytest.raises(MoveError, match="X stopped short of its target") as raised:
        await motion.run(parse("!moa 10 2"), plan, True)
    assert raised.value.statuses == {"x": "E", "y": "@"}
    assert port.finished_events[0].statuses == {"x": "E", "y": "@"}
