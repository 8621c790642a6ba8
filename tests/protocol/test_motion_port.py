""":class:`tango_aio.motion.Motion` through its five-intent port alone: a fake port, no
link, no controller. Each test records the intents a move used, in order."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import pytest

from tango_aio.errors import ControllerError, LimitSwitchActiveError, MoveError
from tango_aio.events import MoveFinished
from tango_aio.instructions import Command, parse
from tango_aio.motion import Motion, MotionPort, MovePlan
from tango_aio.protocol import MoveHandle
from tango_aio.timing import Budget


@dataclass(eq=False)
class _Submission:
    command: Command
    completion: None = None


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

    def start(self, command: Command, batch: object | None) -> MoveHandle:
        self.calls.append(f"start {command.line}")
        return cast(MoveHandle, _Handle(_Submission(command)))

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


async def test_a_refused_line_is_raised_without_a_read() -> None:
    port = _Port(reads=[], refusal=LimitSwitchActiveError(command="!moa x 10"))
    motion = Motion(cast(MotionPort, port))
    with pytest.raises(LimitSwitchActiveError):
        await motion.run(parse("!moa x 10"), _planner({"x": 10.0}), True)
    assert port.calls == ["start !moa x 10", "accepted"]
