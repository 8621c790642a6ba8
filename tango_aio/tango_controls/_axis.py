"""The asyncio side of the device server, without pytango: one :class:`AxisCore` per axis
(its motions, settings and shown state) and the :class:`StageLink` that reads the
controller for all of them and follows the driver's events.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from ..controller import Controller
from ..errors import MoveError, TangoError
from ..events import ConnectionLost, ControllerRestarted, Reconnected
from ..status import MOVING
from ..units import DIM_UNITS
from ._state import AxisView, Shown, shown

__all__ = ["AxisBusyError", "AxisCore", "LimitError", "StageLink"]

log = logging.getLogger("tango_aio.tango_controls")

#: Called with an attribute's name and its new value, or ``"State"`` and
#: ``(Shown, status)``: the device pushes the change event.
Publish = Callable[[str, Any], None]


class AxisBusyError(ValueError):
    """A motion was asked of an axis whose motion has no verdict yet (Stop it first)."""


class LimitError(ValueError):
    """A target beyond the axis's soft limits, refused before anything is written."""


def _ignore(name: str, value: Any) -> None:
    """A publisher for an axis no device shows yet."""


def switches(readsw: str, axis: str) -> tuple[bool, bool, bool]:
    """The lower (E0), upper (EE) and reference switch of ``axis`` in a ``?readsw``
    reply (manual L5027-5080: 12 digits, E0 of X Y Z A, then Ref, then EE); a reply of
    another length reads as none actuated."""
    text = readsw.strip()
    index = "xyza".index(axis)
    if len(text) < 12:
        return False, False, False
    return text[index] == "1", text[8 + index] == "1", text[4 + index] == "1"


class AxisCore:
    """One axis as its Tango Controls device sees it: positions in the axis's dim unit,
    user position = dial position + :attr:`offset`."""

    def __init__(self, controller: Controller, letter: str) -> None:
        self.controller = controller
        self.letter = letter
        self.publish: Publish = _ignore
        self.view = AxisView(link_up=controller.connected)
        self.dial = 0.0
        self.offset = 0.0
        self.unit = ""
        self.switches = (False, False, False)
        self.calibrated = False
        #: Verdicts so far: a read under way when one came is dropped.
        self.verdicts = 0
        self._tasks: set[asyncio.Task[None]] = set()

    # -- what clients read ---------------------------------------------------------------

    @property
    def position(self) -> float:
        """The user position (dial + offset) the server last confirmed or read."""
        return self.dial + self.offset

    @property
    def state(self) -> tuple[Shown, str]:
        """The ``State`` and ``Status`` to show."""
        return shown(self.view)

    def _show(self, view: AxisView) -> None:
        before = shown(self.view)
        self.view = view
        after = shown(view)
        if after != before:
            self.publish("State", after)

    def _set_dial(self, dial: float, *, force: bool = False) -> None:
        if dial != self.dial or force:
            self.dial = dial
            self.publish("Position", self.position)
            self.publish("DialPosition", dial)

    # -- settings ------------------------------------------------------------------------

    async def read_settings(self) -> None:
        """Read the axis's unit, position, switches and calibration, then show it ready."""
        c = self.controller
        dim = int(await c.get("dim", axis=self.letter))
        self.unit = DIM_UNITS[dim].ascii if dim in DIM_UNITS else f"dim {dim}"
        await c.axis_limits(self.letter, cached=False)
        await self.read_slow()
        if not self.view.busy:
            self._set_dial(float(await c.get("pos", axis=self.letter)), force=True)
        self._show(self.view.settings_read())

    async def read_slow(self) -> None:
        """Read the limit switches and the calibration flag."""
        c = self.controller
        found = switches(await c.query("?readsw"), self.letter)
        if found != self.switches:
            self.switches = found
            self.publish("LimitSwitches", list(found))
        calibrated = await c.is_calibrated(self.letter)
        if calibrated != self.calibrated:
            self.calibrated = calibrated
            self.publish("Calibrated", calibrated)

    def link(self, up: bool) -> None:
        """The link went down or came back (ready again once :meth:`read_settings` ran)."""
        if up != self.view.link_up:
            self._show(self.view.link(up))

    def restarted(self) -> None:
        """The controller restarted behind the link: positions and calibration are gone."""
        self._show(AxisView(link_up=self.view.link_up, busy=self.view.busy,
                            alarm="the controller restarted (position counters at 0, "
                                  "calibration lost)", last=self.view.last or "standing"))

    def read(self, verdicts: int, letter: str, dial: float) -> None:
        """Apply a state read that started when :attr:`verdicts` was ``verdicts``."""
        if verdicts != self.verdicts:
            return  # a motion ended while this read was on the wire: older news
        self._set_dial(dial)
        if not self.view.busy:
            self._show(self.view.read(letter == MOVING))

    # -- motions -------------------------------------------------------------------------

    async def move_to(self, target: float) -> None:
        """Start a move to the user position ``target`` and return once it is under way."""
        dial = target - self.offset
        self._check_free()
        targets: dict[str, Any] = {self.letter: dial}
        self.controller.validate_move(**targets)
        low, high = await self.controller.axis_limits(self.letter)
        if not low <= dial <= high and (low, high) != (0.0, 0.0):
            raise LimitError(f"{self.letter.upper()}: target {target:g} (dial {dial:g}) is "
                             f"outside the soft limits [{low + self.offset:g}, "
                             f"{high + self.offset:g}]")
        self._launch(f"move to {target:g}",
                     lambda: self.controller.move_to(**targets))

    async def move_by(self, distance: float) -> None:
        """Start a relative move and return once it is under way."""
        self._check_free()
        distances: dict[str, Any] = {self.letter: distance}
        self.controller.validate_move(relative=True, **distances)
        self._launch(f"move by {distance:g}", lambda: self.controller.move_by(**distances))

    def calibrate(self) -> None:
        """Start a calibration (``cal``: to the lower limit switch, origin set there)."""
        self._check_free()
        self._launch("calibration", lambda: self.controller.calibrate(self.letter))

    def measure_range(self) -> None:
        """Start a range measurement (``rm``: to the upper limit switch)."""
        self._check_free()
        self._launch("range measurement",
                     lambda: self.controller.measure_range(self.letter))

    async def stop(self) -> None:
        """Stop this axis (``a x``, manual L6785-6844) and return once it stands."""
        await self.controller.stop(self.letter)

    def _check_free(self) -> None:
        if not self.controller.connected:
            raise TangoError(f"{self.letter.upper()}: the link to the controller is lost")
        if not self.view.ready:
            raise TangoError(f"{self.letter.upper()}: the axis settings are being read; "
                             "try again once State leaves INIT")
        if self.view.busy:
            raise AxisBusyError(f"{self.letter.upper()}: {self.view.last} is under way; "
                                "Stop it first")

    def _launch(self, what: str, motion: Callable[[], Awaitable[Any]]) -> None:
        self._show(self.view.started(what))
        task = asyncio.get_running_loop().create_task(self._motion(motion))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _motion(self, motion: Callable[[], Awaitable[Any]]) -> None:
        reason: str | None = None
        try:
            await motion()
        except MoveError as exc:
            reason = str(exc)
        except TangoError as exc:
            reason = f"{type(exc).__name__}: {exc}"
        except asyncio.CancelledError:
            self.verdicts += 1
            raise
        confirmed = None if reason else (self.controller.last_positions or {}).get(
            self.letter)
        self.verdicts += 1  # reads under way now carry older news
        dial: float | None = None
        if confirmed is not None:
            with contextlib.suppress(ValueError):
                dial = float(confirmed)
        if dial is None:
            with contextlib.suppress(TangoError):
                dial = float(await self.controller.get("pos", axis=self.letter))
        if dial is not None:
            self._set_dial(dial, force=True)  # the final Position event, before the State's
        self._show(self.view.ended(reason))
        if reason:
            log.warning("%s: %s", self.letter.upper(), reason)

    async def aclose(self) -> None:
        """Cancel the motions in flight (the driver stops their axes)."""
        for task in list(self._tasks):
            task.cancel()
        if self._tasks:
            await asyncio.wait(list(self._tasks))


class StageLink:
    """Reads one controller for all its axis devices and follows its events."""

    #: State reads per read of the switches and the calibration flags.
    SLOW_EVERY = 5

    def __init__(self, controller: Controller, interval: float = 0.1) -> None:
        self.controller = controller
        self.interval = interval
        count = controller.identity.axes if controller.connected else controller.context.axes
        self.axes = {letter: AxisCore(controller, letter) for letter in "xyza"[:count]}
        self._wake = asyncio.Event()
        self._up = False
        #: Set once the first read of the settings has been tried.
        self.first_read = asyncio.Event()

    async def run(self) -> None:
        """Read and follow until cancelled."""
        async with asyncio.TaskGroup() as group:
            group.create_task(self._follow_events())
            group.create_task(self._poll())

    async def _follow_events(self) -> None:
        async with self.controller.events() as events:
            async for event in events:
                if isinstance(event, ConnectionLost):
                    self._set_link(False)
                elif isinstance(event, Reconnected):
                    self._wake.set()
                elif isinstance(event, ControllerRestarted):
                    for axis in self.axes.values():
                        axis.restarted()
                    self._up = False
                    self._wake.set()

    def _set_link(self, up: bool) -> None:
        self._up = self._up and up
        for axis in self.axes.values():
            axis.link(up)

    async def _poll(self) -> None:
        count = 0
        while True:
            try:
                await self._poll_once(slow=count % self.SLOW_EVERY == 0)
            except TangoError as exc:
                if self.controller.connected:
                    log.warning("state read failed: %s", exc)
            self.first_read.set()
            count += 1
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(self.interval):
                    await self._wake.wait()

    async def _poll_once(self, *, slow: bool) -> None:
        c = self.controller
        if not c.connected:
            self._set_link(False)
            return
        if not self._up:
            self._set_link(True)
            for axis in self.axes.values():
                await axis.read_settings()
            self._up = True
            return
        seen = {letter: axis.verdicts for letter, axis in self.axes.items()}
        letters = await c.status()
        positions = await c.position()
        for letter, axis in self.axes.items():
            if letter in positions:
                axis.read(seen[letter], letters.get(letter, "@"), positions[letter])
        if slow:
            for axis in self.axes.values():
                await axis.read_slow()

    async def abort(self) -> None:
        """Stop every axis (``a``, manual L6785-6844) and return once they stand."""
        await self.controller.abort(soft=True)

    async def aclose(self) -> None:
        """Cancel every axis's motion in flight (the driver stops those axes)."""
        for axis in self.axes.values():
            await axis.aclose()
