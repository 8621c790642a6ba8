"""What the controller hands over: :class:`_Port` (the controller as
:class:`~tango_aio.controller._motion.Motion` sees it) and :class:`_Devices` (as the
device families see it), each made of the controller's own methods."""

from __future__ import annotations

from collections.abc import (
    Callable,
    Coroutine,
    Mapping,
    Sequence,
)
from dataclasses import dataclass
from typing import Any

from ..catalog import (
    AXES,
    INSTRUCTIONS,
    Command,
    Context,
    Value,
)
from ..errors import (
    ControllerError,
    InvalidInstructionError,
    ProtocolError,
)
from ..events import (
    MoveFinished,
    TangoEvent,
)
from ..families import (
    RESTART_QUIET,
    ListTransfer,
)
from ..link import (
    MoveHandle,
)
from ..units import Measure
from ._planning import _Planning
from ._reads import Identity


@dataclass(frozen=True, slots=True)
class _Port:
    """The controller as :class:`~tango_aio.controller._motion.Motion` sees it
    (``MotionPort``): the controller's own methods, handed over."""

    start: Callable[[Command, object | None], MoveHandle]
    accepted: Callable[[MoveHandle], Coroutine[Any, Any, ControllerError | None]]
    stop: Callable[[], Coroutine[Any, Any, None]]
    read_state: Callable[[Sequence[str]],
                         Coroutine[Any, Any, tuple[dict[str, str], dict[str, str]]]]
    finished: Callable[[MoveFinished], None]
    unreported: Callable[[], None]


class _Devices:
    """The port of the device families: the controller's own methods."""

    __slots__ = ("_controller",)

    def __init__(self, controller: _Planning) -> None:
        self._controller = controller

    @property
    def context(self) -> Context:
        return self._controller.context

    @property
    def identity(self) -> Identity:
        return self._controller.identity

    @property
    def units(self) -> str | None:
        return self._controller.units

    @units.setter
    def units(self, value: str | None) -> None:
        self._controller.units = value

    async def refresh_settings(self) -> None:
        await self._controller.refresh_settings()

    async def wait_restarted(self, *, quiet: float = RESTART_QUIET) -> None:
        await self._controller.wait_restarted(quiet=quiet)

    @property
    def axes(self) -> tuple[str, ...]:
        known = self._controller._identity
        return tuple(AXES[: known.axes if known else self._controller.context.axes])

    async def get(self, name: str, *args: Value, axis: str | None = None,
                  timeout: float | None = None) -> Any:
        return await self._controller.get(name, *args, axis=axis, timeout=timeout)

    async def set(self, name: str, /, *args: Value, axis: str | None = None,
                  check: bool = True, **axes: Any) -> None:
        await self._controller.set(name, *args, axis=axis, check=check, **axes)

    async def query(self, line: str, timeout: float | None = None) -> str:
        return await self._controller.query(line, timeout)

    async def command(self, line: str, *, check: bool = True,
                      timeout: float | None = None) -> None:
        await self._controller.command(line, check=check, timeout=timeout)

    async def read_if_known(self, name: str) -> Any:
        controller = self._controller
        known = controller._identity
        if known is not None and known.family == "older" \
                and not INSTRUCTIONS[name].in_older_manual:
            return None
        try:
            return await controller._read_or_absent(name)
        except (InvalidInstructionError, ProtocolError):
            return None

    async def state(self) -> tuple[dict[str, str], dict[str, str]]:
        return await self._controller._status_and_positions()

    async def user_positions(self, texts: Mapping[str, str]) -> dict[str, float]:
        controller = self._controller
        return await controller._from_controller(
            texts, controller._reading_unit(None, Measure.POSITION), Measure.POSITION)

    def publish(self, event: TangoEvent) -> None:
        self._controller._hub.publish(event)

    def moving(self) -> bool:
        return self._controller._motion.busy or bool(self._controller._motion_calls)

    def list_transfer(self) -> ListTransfer:
        return self._controller._transfer()

    async def resolution(self) -> list[float]:
        return await self._controller._resolution()

    def check_axes(self, command: Command) -> None:
        self._controller._check_axes(command)
