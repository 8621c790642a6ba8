"""A controller as an ophyd-async stage with one child axis per letter, and its plan stubs."""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from typing import Any

try:
    import bluesky.plan_stubs as bps
    from bluesky.utils import MsgGenerator
    from ophyd_async.core import StandardReadable
except ImportError as exc:  # pragma: no cover - depends on the environment
    from .._install import install_hint

    raise ImportError(f"tango_aio.bluesky needs the bluesky extra: "
                      f"{install_hint('bluesky')}") from exc

from ..catalog import AXES
from ..controller import Controller
from ..errors import MissingAxisError
from ._axis import MarzhauserAxis
from ._link import StageLink, _LinkConnector


class MarzhauserStage(StandardReadable):
    """A TANGO controller as an ophyd-async device with one child axis per letter.

    ``MarzhauserStage(url, axes="xy", name="stage", **connect_options)``:
    ``connect_options`` go to :func:`tango_aio.connect`. Sets of different axes that the
    RunEngine starts together (``bps.mv(stage.x, 1, stage.y, 2)``) are merged into one
    move: each ``set()`` announces itself when called, and a move waits for the sets
    announced while it was being collected, but never for time alone (a single set
    waits for nothing); ``window`` (0.25 s) bounds that wait. ``progress_interval`` (0.1 s)
    how often positions are polled while a move runs. ``stage.x``, ``stage.y``... (or
    ``stage.axis("x")``) are the :class:`MarzhauserAxis` children; ``read()`` reads them
    all. Close with ``await stage.aclose()`` (or the :func:`close_stage` plan stub).

    Parameters
    ----------
    url
        The controller's URL.
    axes
        The axis letters, distinct, of ``xyza``.
    name
        The device name.
    window
        The longest wait for sets announced together, in seconds.
    progress_interval
        Seconds between two position reads while a move runs.
    **connect_options
        Options of :func:`tango_aio.connect`.

    Raises
    ------
    ValueError
        ``axes`` are not distinct axis letters.
    """

    x: MarzhauserAxis
    y: MarzhauserAxis
    z: MarzhauserAxis
    a: MarzhauserAxis

    def __init__(self, url: str, axes: str = "xy", name: str = "stage", *,
                 window: float = 0.25, progress_interval: float = 0.1,
                 **connect_options: Any) -> None:
        letters = axes.lower()
        if not letters or len(set(letters)) != len(letters) or set(letters) - set(AXES):
            raise ValueError(f"axes must be distinct letters of {AXES!r}, got {axes!r}")
        self._link = StageLink(url, letters, connect_options, window=window,
                               progress_interval=progress_interval)
        self._axes: dict[str, MarzhauserAxis] = {}
        with self.add_children_as_readables():
            for letter in letters:
                axis = MarzhauserAxis(self._link, letter)
                setattr(self, letter, axis)
                self._axes[letter] = axis
        super().__init__(name=name, connector=_LinkConnector(self._link))

    @property
    def link(self) -> StageLink:
        """The link shared by the axes (and by flyers made for this stage)."""
        return self._link

    @property
    def controller(self) -> Controller:
        """The open controller (after ``connect()``), for anything the devices lack."""
        return self._link.controller

    def axis(self, letter: str) -> MarzhauserAxis:
        """The child axis ``letter``.

        Parameters
        ----------
        letter
            The axis letter (``"x"``...).

        Returns
        -------
        MarzhauserAxis
            The child device of that axis.

        Raises
        ------
        MissingAxisError
            The stage has no such axis.
        """
        try:
            return self._axes[letter.lower()]
        except KeyError:
            raise MissingAxisError(f"{self.name} has no axis {letter!r}") from None

    async def refresh_settings(self) -> None:
        """Read units, unit scales (``dim``, ``pitch``, ``gear``, ``usteps``), limits
        and precision again: call it after changing them on the controller. Until then
        the axes convert with what was read at connect."""
        await self._link.refresh()
        for axis in self._axes.values():
            axis._set_units()

    async def aclose(self) -> None:
        """Stop what the devices move and close the controller."""
        await self._link.aclose()


def _await_statuses(start: Callable[[], Sequence[Awaitable[Any]]]) -> MsgGenerator[None]:
    """Plan stub: start statuses on the RunEngine's loop, wait for them in turn, and
    raise the first failure in the plan (``bps.wait_for`` alone swallows it)."""
    errors: list[BaseException] = []

    async def wait() -> None:
        for status in start():
            try:
                await status
            except Exception as exc:
                errors.append(exc)

    yield from bps.wait_for([wait])
    if errors:
        raise errors[0]


def home(*axes: MarzhauserAxis) -> MsgGenerator[None]:
    """Plan stub: calibrate (``!cal``) each axis in turn (:meth:`MarzhauserAxis.home`);
    the plan fails with the controller's failure.

    Parameters
    ----------
    *axes
        The axes to calibrate, in this order.

    Returns
    -------
    MsgGenerator[None]
        The plan.
    """
    return _await_statuses(lambda: [axis.home() for axis in axes])


def measure_range(*axes: MarzhauserAxis) -> MsgGenerator[None]:
    """Plan stub: range measure (``!rm``) each axis in turn
    (:meth:`MarzhauserAxis.measure_range`); the plan fails with the controller's failure.

    Parameters
    ----------
    *axes
        The axes to measure, in this order.

    Returns
    -------
    MsgGenerator[None]
        The plan.
    """
    return _await_statuses(lambda: [axis.measure_range() for axis in axes])


def close_stage(stage: MarzhauserStage) -> MsgGenerator[None]:
    """Plan stub: close the stage's controller on the RunEngine's loop.

    Parameters
    ----------
    stage
        The stage whose controller to close.

    Yields
    ------
    Msg
        The plan's messages.
    """
    yield from bps.wait_for([stage.aclose])
