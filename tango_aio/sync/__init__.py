"""The blocking API, for scripts and notebooks: ``tango_aio.sync.connect(url)``.

::

    import tango_aio.sync

    with tango_aio.sync.connect("sim://?axes=3") as tango:
        tango.move_to(x=10, y=5)          # returns when both axes are there
        print(tango.position(unit="mm"))
        future = tango.start_move_to(x=0)  # returns at once: a concurrent.futures.Future
        tango.wait_idle()
        print(future.result())

How it works: the driver's event loop runs in a thread of its own (an anyio blocking
portal), so this works in plain scripts and equally inside a running event loop (Jupyter,
an IPython kernel), where ``asyncio.run()`` cannot be used. Every blocking method is made
from the async method of the same name (same parameters, same docstring, same types);
:attr:`Controller.aio` is the async object underneath.

Ctrl+C (:class:`KeyboardInterrupt`) during a blocking call cancels it in the driver's
thread, exactly like cancelling the awaited call: a move stops its axes (unless
``stop_on_cancel=False``) and the interrupt is re-raised once they stand still (at most
:data:`STOP_WAIT` seconds later). ``start_*`` methods return a
:class:`concurrent.futures.Future`; cancelling that future cancels the move the same way.
Ctrl+C in *any* blocking call (``wait_idle()``, ``get()``, ``position()``, an event
iterator...) also cancels every ``start_*`` call of this program still running, on every
blocking object, so what the program started stops too; so does Ctrl+C while a
``start_*`` call is being started.

:class:`ControllerGroup` is the blocking twin of :class:`tango_aio.ControllerGroup`; its
members (``group["stage"]``) are blocking controllers on the group's thread.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import inspect
import weakref
from collections.abc import (
    Awaitable,
    Callable,
    Iterable,
    Iterator,
    Mapping,
)
from types import TracebackType
from typing import Any, ParamSpec, TypeVar

from .. import controller as _connection
from ..controller import Controller as AsyncController
from ..controller import Identity
from ..events import PositionUpdate, Subscription, TangoEvent
from ..group import ControllerGroup as AsyncGroup
from ..group import ControllerSpec, GroupEvent, GroupSubscription
from ._blocking import _Blocking, _Starter, _Wrapper
from ._families import IO, ClosedLoop, Encoders, Info, Joystick, Settings, Snapshots, Triggers
from ._portal import STOP_WAIT, Portal, stop_started

__all__ = ["IO", "STOP_WAIT", "ClosedLoop", "Controller", "ControllerGroup", "Encoders",
           "Info", "Joystick", "Portal", "Settings", "Snapshots", "Triggers", "connect",
           "stop_started"]

P = ParamSpec("P")
T = TypeVar("T")


#: Blocking objects not closed yet; closed at interpreter exit.
_OPEN: weakref.WeakSet[Controller | ControllerGroup] = weakref.WeakSet()


@atexit.register
def _close_open() -> None:
    for wrapper in list(_OPEN):
        with contextlib.suppress(Exception):
            wrapper.close()


class Controller(_Wrapper[AsyncController]):
    """A connected TANGO controller, blocking. Get one with :func:`connect`.

    Every method is the blocking form of the :class:`tango_aio.Controller` method of the
    same name (see there); ``close()`` is ``aclose()``. ``start_move_to(...)`` and the
    other ``start_*`` methods return a :class:`concurrent.futures.Future` at once.
    """

    # -- the blocking methods, one per async method (tests/e2e/test_sync.py checks that none
    # -- is missing)
    setup = _Blocking(AsyncController.setup)
    wait_connected = _Blocking(AsyncController.wait_connected)
    identify = _Blocking(AsyncController.identify)
    refresh_settings = _Blocking(AsyncController.refresh_settings)
    query = _Blocking(AsyncController.query)
    command = _Blocking(AsyncController.command)
    get = _Blocking(AsyncController.get)
    set = _Blocking(AsyncController.set)
    position = _Blocking(AsyncController.position)
    status = _Blocking(AsyncController.status)
    axis_status = _Blocking(AsyncController.axis_status)
    move_to = _Blocking(AsyncController.move_to)
    move_by = _Blocking(AsyncController.move_by)
    calibrate = _Blocking(AsyncController.calibrate)
    measure_range = _Blocking(AsyncController.measure_range)
    move_to_center = _Blocking(AsyncController.move_to_center)
    go = _Blocking(AsyncController.go)
    speed = _Blocking(AsyncController.speed)
    stop = _Blocking(AsyncController.stop)
    abort = _Blocking(AsyncController.abort)
    check_fault = _Blocking(AsyncController.check_fault)
    is_calibrated = _Blocking(AsyncController.is_calibrated)
    axis_limits = _Blocking(AsyncController.axis_limits)
    read_info = _Blocking(AsyncController.read_info)
    wait_restarted = _Blocking(AsyncController.wait_restarted)

    # -- non-blocking starts (Zaber's wait_until_idle=False)
    start_move_to = _Starter(AsyncController.move_to)
    start_move_by = _Starter(AsyncController.move_by)
    start_calibrate = _Starter(AsyncController.calibrate)
    start_measure_range = _Starter(AsyncController.measure_range)
    start_move_to_center = _Starter(AsyncController.move_to_center)

    def wait_idle(self, *, poll_interval: float = 0.05,
                  timeout: float | None = None) -> dict[str, str]:
        """Wait until every ``start_*`` move of this object has finished (raising the
        first one's error, e.g. :class:`~tango_aio.MoveError`), then until no axis moves
        (:meth:`tango_aio.Controller.wait_idle`); return the status letters.

        Parameters
        ----------
        poll_interval
            Seconds between two status reads.
        timeout
            Seconds to wait for the axes at most; ``None`` waits without limit.

        Returns
        -------
        dict[str, str]
            The status letter of each axis.
        """
        self._join_started()
        return self._portal.call(self.aio.wait_idle, poll_interval=poll_interval,
                                 timeout=timeout)

    def is_busy(self) -> bool:
        """Whether a ``start_*`` move of this object is still running, or
        :meth:`tango_aio.Controller.is_busy`.

        Returns
        -------
        bool
            True while a started move runs or an axis moves.
        """
        if any(not future.done() for future in self._started):
            return True
        return self._portal.call(self.aio.is_busy)

    def watch_position(self, interval: float = 0.1, *, follow: bool = False,
                       unit: str | None = None) -> Iterator[PositionUpdate]:
        """Blocking iterator over :meth:`tango_aio.Controller.watch_position`.

        Parameters
        ----------
        interval
            Seconds between two position reads.
        follow
            Keep reading after the axes have stopped, until the loop is left.
        unit
            The unit of the positions (e.g. ``"mm"``); ``None`` for the controller's own.

        Returns
        -------
        Iterator[PositionUpdate]
            The position updates, read in the driver's thread.
        """
        return self._portal.iterate(self.aio.watch_position(interval, follow=follow,
                                                            unit=unit))

    def events(self, maxsize: int = 256) -> Iterator[TangoEvent]:
        """Blocking iterator over :meth:`tango_aio.Controller.events` (subscribed now).

        Parameters
        ----------
        maxsize
            How many events the subscription holds before it drops the oldest.

        Returns
        -------
        Iterator[TangoEvent]
            The controller's events from now on.
        """
        subscription: Subscription = self._portal.call(_subscribe, self.aio, maxsize)
        return self._portal.iterate(subscription)

    @functools.cached_property
    def joystick(self) -> Joystick:
        """The HDI, blocking (:attr:`tango_aio.Controller.joystick`)."""
        return Joystick(self.aio.joystick, self._portal, owns_portal=False)

    @functools.cached_property
    def io(self) -> IO:
        """Digital and analogue I/O, blocking (:attr:`tango_aio.Controller.io`)."""
        return IO(self.aio.io, self._portal, owns_portal=False)

    @functools.cached_property
    def encoders(self) -> Encoders:
        """The encoders, blocking (:attr:`tango_aio.Controller.encoders`)."""
        return Encoders(self.aio.encoders, self._portal, owns_portal=False)

    @functools.cached_property
    def closed_loop(self) -> ClosedLoop:
        """Closed loop, blocking (:attr:`tango_aio.Controller.closed_loop`)."""
        return ClosedLoop(self.aio.closed_loop, self._portal, owns_portal=False)

    @functools.cached_property
    def triggers(self) -> Triggers:
        """The trigger output and list, blocking (:attr:`tango_aio.Controller.triggers`)."""
        return Triggers(self.aio.triggers, self._portal, owns_portal=False)

    @functools.cached_property
    def snapshots(self) -> Snapshots:
        """The snapshot input and array, blocking (:attr:`tango_aio.Controller.snapshots`)."""
        return Snapshots(self.aio.snapshots, self._portal, owns_portal=False)

    def validate_move(self, /, *, relative: bool = False, **axes: float) -> None:
        """Check move targets without moving (see
        :meth:`tango_aio.Controller.validate_move`); raises
        :class:`~tango_aio.errors.InvalidCommandError`. Runs in the caller's thread: it
        reads the cached context only.

        Parameters
        ----------
        relative
            Check ``axes`` as distances from the current position, not as targets.
        **axes
            Target (or distance) of each axis, by axis name (``x=1.0``).

        Raises
        ------
        InvalidCommandError
            A target is not valid (see :meth:`tango_aio.Controller.validate_move`).
        """
        self.aio.validate_move(relative=relative, **axes)

    @functools.cached_property
    def settings(self) -> Settings:
        """The blocking twin of :attr:`tango_aio.Controller.settings`: every setting by
        name, snapshot, diff, restore, save (each method blocks)."""
        return Settings(self.aio.settings, self._portal, owns_portal=False)

    @functools.cached_property
    def info(self) -> Info:
        """The blocking twin of :attr:`tango_aio.Controller.info` (each method blocks)."""
        return Info(self.aio.info, self._portal, owns_portal=False)

    @property
    def identity(self) -> Identity:
        """The identity read when connecting (see :attr:`tango_aio.Controller.identity`)."""
        return self.aio.identity

    @property
    def url(self) -> str:
        """The URL this controller was opened with."""
        return self.aio.url

    @property
    def units(self) -> str | None:
        """The connection's physical position unit (``None``: the dim unit)."""
        return self.aio.units

    @property
    def autostatus(self) -> int:
        """The autostatus mode the driver believes is in force."""
        return self.aio.autostatus

    @property
    def connected(self) -> bool:
        """Whether the link is up."""
        return self.aio.connected

    def close(self) -> None:
        """Close the connection (``aclose()``) and stop the driver's thread."""
        _OPEN.discard(self)
        try:
            self._portal.call(self.aio.aclose)
        finally:
            if self._owns_portal:
                self._portal.stop()

    def __enter__(self) -> Controller:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        _leave(self, exc)

    def __repr__(self) -> str:
        return f"<tango_aio.sync.Controller {self.url!r}>"


def _leave(wrapper: Controller | ControllerGroup, exc: BaseException | None) -> None:
    """Leave a ``with`` block: on Ctrl+C (wherever it landed in the block, even between
    two calls), stop what ``start_*`` calls started first (:func:`stop_started`), then
    close."""
    if isinstance(exc, KeyboardInterrupt):
        stop_started()
    wrapper.close()


async def _subscribe(controller: AsyncController | AsyncGroup, maxsize: int) -> Any:
    return controller.events(maxsize)


def _parameters_of(source: Callable[P, object]
                   ) -> Callable[[Callable[..., T]], Callable[P, T]]:
    """Give the decorated function ``source``'s parameters (for type checkers, editors
    and ``inspect.signature``), keeping its own return type and docstring."""
    def decorate(func: Callable[..., T]) -> Callable[P, T]:
        own = inspect.signature(func).return_annotation
        func.__signature__ = inspect.signature(source).replace(  # type: ignore[attr-defined]
            return_annotation=own)
        return func
    return decorate


@_parameters_of(_connection.connect)
def connect(url: str = "sim://", **options: Any) -> Controller:
    """Connect to a TANGO controller and return a blocking :class:`Controller`.

    Takes exactly the options of :func:`tango_aio.connect` (a misspelt one raises
    :class:`TypeError` before anything is opened). Close it with ``close()``, or use it
    as a context manager (``with tango_aio.sync.connect(url) as tango:``).

    Parameters
    ----------
    url
        Where the controller is (``"sim://"``, ``"/dev/ttyUSB0"``, ``"socket://host:port"``,
        see :func:`tango_aio.connect`).
    **options
        The options of :func:`tango_aio.connect`.

    Returns
    -------
    Controller
        The connected blocking controller, with a driver thread of its own.

    Raises
    ------
    TypeError
        An unknown option.
    ValueError
        An invalid option or URL, before anything is opened.
    ConnectError
        The link cannot be set up (see :func:`tango_aio.connect`).
    """
    connecting = _connection.connect(url, **options)  # checks the options first
    portal = Portal()
    try:
        controller = portal.call(_await, connecting)
    except BaseException:
        portal.stop()
        raise
    wrapper = Controller(controller, portal, owns_portal=True)
    _OPEN.add(wrapper)
    return wrapper


async def _await(awaitable: Awaitable[T]) -> T:
    return await awaitable


class ControllerGroup(_Wrapper[AsyncGroup], Mapping[str, Controller]):
    """Several controllers driven concurrently, blocking: the twin of
    :class:`tango_aio.ControllerGroup` (same arguments and methods). Opened by the
    constructor; close it with ``close()`` or use it as a context manager. Members are
    blocking :class:`Controller` objects on the group's thread.

    Parameters
    ----------
    controllers
        A URL, or ``(url, options)``, by member name.
    **options
        Options of :func:`tango_aio.connect` for every member.
    """

    def __init__(self, controllers: Mapping[str, ControllerSpec], **options: Any) -> None:
        portal = Portal()
        try:
            group = AsyncGroup(controllers, **options)
            portal.call(group.open)
        except BaseException:
            portal.stop()
            raise
        super().__init__(group, portal, owns_portal=True)
        self._members = {name: Controller(member, portal, owns_portal=False)
                         for name, member in group.items()}
        _OPEN.add(self)

    each = _Blocking(AsyncGroup.each)
    move_to = _Blocking(AsyncGroup.move_to)
    move_by = _Blocking(AsyncGroup.move_by)
    calibrate = _Blocking(AsyncGroup.calibrate)
    measure_range = _Blocking(AsyncGroup.measure_range)
    stop = _Blocking(AsyncGroup.stop)
    abort = _Blocking(AsyncGroup.abort)
    position = _Blocking(AsyncGroup.position)
    status = _Blocking(AsyncGroup.status)

    start_move_to = _Starter(AsyncGroup.move_to)
    start_move_by = _Starter(AsyncGroup.move_by)
    start_calibrate = _Starter(AsyncGroup.calibrate)
    start_measure_range = _Starter(AsyncGroup.measure_range)

    def wait_idle(self, names: Iterable[str] | None = None, **options: Any
                  ) -> dict[str, dict[str, str]]:
        """Wait for every ``start_*`` call of the group (raising the first one's error),
        then :meth:`Controller.wait_idle` of every member (or those in ``names``),
        concurrently; returns name → letters.

        Parameters
        ----------
        names
            The members to wait for; ``None`` for all of them.
        **options
            The options of :meth:`Controller.wait_idle` (``poll_interval``, ``timeout``).

        Returns
        -------
        dict[str, dict[str, str]]
            The status letters of each member, by member name.
        """
        self._join_started()
        selected = list(self) if names is None else list(names)

        async def wait_all() -> dict[str, dict[str, str]]:
            return await self.aio.each(lambda c: c.wait_idle(**options), selected)

        return self._portal.call(wait_all)

    def events(self, maxsize: int = 256) -> Iterator[GroupEvent]:
        """Blocking iterator over :meth:`tango_aio.ControllerGroup.events`.

        Parameters
        ----------
        maxsize
            How many events the subscription holds before it drops the oldest.

        Returns
        -------
        Iterator[GroupEvent]
            The members' events from now on, each with its member's name.
        """
        subscription: GroupSubscription = self._portal.call(_subscribe, self.aio, maxsize)
        return self._portal.iterate(subscription)

    def __getitem__(self, name: str) -> Controller:
        return self._members[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._members)

    def __len__(self) -> int:
        return len(self._members)

    def __eq__(self, other: object) -> bool:
        return self is other

    def __hash__(self) -> int:
        return id(self)

    def url(self, name: str) -> str:
        """The URL of member ``name``.

        Parameters
        ----------
        name
            The member's name.

        Returns
        -------
        str
            The URL that member was opened with.
        """
        return self.aio.url(name)

    def close(self) -> None:
        """Close every member (``aclose()``) and stop the driver's thread."""
        _OPEN.discard(self)
        try:
            self._portal.call(self.aio.aclose)
        finally:
            self._portal.stop()

    def __enter__(self) -> ControllerGroup:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        _leave(self, exc)
