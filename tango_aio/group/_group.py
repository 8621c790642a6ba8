"""Several controllers at once: :class:`ControllerGroup`."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import (
    Awaitable,
    Callable,
    Iterable,
    Iterator,
    Mapping,
    Sequence,
)
from types import TracebackType
from typing import Any, NamedTuple, TypeVar

import anyio

from ..controller import Controller, connect
from ..errors import InvalidCommandError
from ..events import Subscription, TangoEvent
from ..stream import BoundedStream

__all__ = [
    "ControllerGroup",
    "ControllerSpec",
    "GroupError",
    "GroupEvent",
    "GroupSubscription",
]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: How a group member is given: a URL, or a URL with :func:`~tango_aio.connect` options.
ControllerSpec = str | tuple[str, Mapping[str, Any]]

#: Seconds :meth:`ControllerGroup.aclose` allows each controller to close.
CLOSE_TIMEOUT = 5.0
#: Seconds a cancelled member operation may take to clean up (stop its axes).
CANCEL_CLEANUP_TIMEOUT = 15.0


# ----------------------------------------------------------------------------- errors


class GroupError(ExceptionGroup[Exception]):
    """Some members of a :class:`ControllerGroup` failed.

    The grouped exceptions are the members' original exceptions, each with a note naming
    its controller. ``failures`` maps controller name → exception, ``results`` maps the
    name of each member that succeeded to what it returned, and ``cancelled`` names the
    members whose operation was cancelled because of ``fail_fast``.

    Parameters
    ----------
    message
        The message.
    failures
        The exception of each failed member, by name.
    results
        The result of each member that succeeded, by name.
    cancelled
        The members cancelled because of ``fail_fast``.
    """

    failures: dict[str, Exception]
    results: dict[str, Any]
    cancelled: tuple[str, ...]

    def __new__(cls, message: str, failures: Mapping[str, Exception],
                results: Mapping[str, Any] | None = None,
                cancelled: Sequence[str] = ()) -> GroupError:
        self = super().__new__(cls, message, list(failures.values()))
        self.failures = dict(failures)
        self.results = dict(results or {})
        self.cancelled = tuple(cancelled)
        return self

    def __init__(self, message: str, failures: Mapping[str, Exception],
                 results: Mapping[str, Any] | None = None,
                 cancelled: Sequence[str] = ()) -> None:
        super().__init__(message, list(failures.values()))

    def derive(self, excs: Sequence[Exception]) -> GroupError:  # type: ignore[override]
        """The sub-group ``except*`` and :meth:`split` build: keeps the names.

        Parameters
        ----------
        excs
            The exceptions of the sub-group.

        Returns
        -------
        GroupError
            A group error of those exceptions, with their members' names.
        """
        kept = {name: exc for name, exc in self.failures.items()
                if any(exc is other for other in excs)}
        return GroupError(self.message, kept, self.results, self.cancelled)

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (self.message, self.failures, self.results, self.cancelled))


# ----------------------------------------------------------------------------- events


class GroupEvent(NamedTuple):
    """An event of a group member: ``name, event = group_event``."""

    name: str
    event: TangoEvent


class GroupSubscription(BoundedStream[GroupEvent]):
    """The merged event stream of a group's controllers, tagged with their names.

    Iterate it (``async for name, event in subscription``) inside ``async with`` or call
    :meth:`aclose` when done. Overflow policy, as :class:`~tango_aio.events.Subscription`
    (both are a :class:`~tango_aio.stream.BoundedStream`): the buffer is bounded and a
    subscriber that falls behind loses its *oldest* events, never blocking a controller;
    :attr:`dropped` counts them (this stream's losses and its members'). Events of one
    controller keep their order; across controllers they come in the order they were
    published. Iteration ends once every member's stream has ended (connection lost, whose
    :class:`~tango_aio.events.ConnectionLost` comes through first, or the group closed).

    Each member's events are moved over by a small asyncio task owned by the
    subscription (cancelled by :meth:`close`).

    Parameters
    ----------
    members
        The subscription of each member, by name.
    maxsize
        How many events it holds before it drops the oldest.
    """

    def __init__(self, members: Mapping[str, Subscription], maxsize: int) -> None:
        super().__init__(maxsize)
        self._members = dict(members)
        self._running = len(self._members)
        loop = asyncio.get_running_loop()
        self._tasks = [loop.create_task(self._forward(name, subscription),
                                        name=f"tango_aio group events {name!r}")
                       for name, subscription in self._members.items()]
        if not self._tasks:
            self.end()

    @property
    def dropped(self) -> int:
        """Events lost because a buffer was full (this one's or a member's)."""
        return super().dropped + sum(sub.dropped for sub in self._members.values())

    async def _forward(self, name: str, subscription: Subscription) -> None:
        try:
            async for event in subscription:
                self.offer(GroupEvent(name, event))
        finally:
            self._running -= 1
            if self._running == 0:
                self.end()

    def close(self) -> None:
        """Stop receiving events; buffered ones are discarded and iteration ends."""
        for subscription in self._members.values():
            subscription.close()
        for task in self._tasks:
            task.cancel()
        super().close()

    async def aclose(self) -> None:
        """Stop receiving events and wait until the forwarding tasks have ended."""
        self.close()
        if self._tasks:
            await asyncio.wait(self._tasks)

    async def __aenter__(self) -> GroupSubscription:
        return self

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        await self.aclose()


# ------------------------------------------------------------------------------ group


class ControllerGroup(Mapping[str, Controller]):
    """Several controllers, opened together and driven concurrently.

    ``controllers`` maps a name to a URL or to ``(url, options)``; ``options`` are
    :func:`~tango_aio.connect` options for every member (a member's own options win)::

        async with ControllerGroup({"stage": "/dev/ttyUSB0",
                                    "focus": ("sim://?axes=1", {"reply_timeout": 2})},
                                   autostatus=1) as group:
            ...

    Or ``group = await ControllerGroup(...).open()`` and later ``await group.aclose()``.

    The group is a read-only mapping name → :class:`~tango_aio.Controller`
    (``group["stage"]``, ``for name in group``, ``group.items()``); controllers are
    available while the group is open. See the module documentation for the failure
    policy shared by all operations.

    Parameters
    ----------
    controllers
        A URL, or ``(url, options)``, by member name.
    **options
        Options of :func:`~tango_aio.connect` for every member.

    Raises
    ------
    ValueError
        A member name is not a non-empty string.
    """

    def __init__(self, controllers: Mapping[str, ControllerSpec], **options: Any) -> None:
        self._specs: dict[str, tuple[str, dict[str, Any]]] = {}
        for name, spec in controllers.items():
            if not isinstance(name, str) or not name:
                raise ValueError(f"controller names must be non-empty strings, got {name!r}")
            if isinstance(spec, str):
                url, own = spec, {}
            else:
                url, own = spec[0], dict(spec[1])
            self._specs[name] = (url, {**options, **own})
        self._controllers: dict[str, Controller] | None = None

    # -- mapping --------------------------------------------------------------------------

    def __getitem__(self, name: str) -> Controller:
        if name not in self._specs:
            raise KeyError(name)
        if self._controllers is None:
            raise RuntimeError("the ControllerGroup is not open")
        return self._controllers[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._specs)

    def __len__(self) -> int:
        return len(self._specs)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def __eq__(self, other: object) -> bool:
        return self is other  # a group is a resource, not a value

    def __hash__(self) -> int:
        return id(self)

    def __repr__(self) -> str:
        state = "open" if self._controllers is not None else "closed"
        members = ", ".join(f"{name}={url!r}" for name, (url, _) in self._specs.items())
        return f"<ControllerGroup {state}: {members}>"

    @property
    def is_open(self) -> bool:
        """Whether :meth:`open` succeeded and :meth:`aclose` has not been called."""
        return self._controllers is not None

    def url(self, name: str) -> str:
        """The URL of member ``name``.

        Parameters
        ----------
        name
            The member's name.

        Returns
        -------
        str
            The URL of that member.
        """
        return self._specs[name][0]

    # -- lifecycle ------------------------------------------------------------------------

    async def open(self) -> ControllerGroup:
        """Connect to every controller concurrently; returns the group.

        If any fails, the ones that opened are closed again and a :class:`GroupError`
        names the failures. If the open is cancelled, the ones that opened are closed too.

        Returns
        -------
        ControllerGroup
            The group itself, open.

        Raises
        ------
        RuntimeError
            The group is already open.
        GroupError
            A member failed to connect.
        """
        if self._controllers is not None:
            raise RuntimeError("the ControllerGroup is already open")
        opened: dict[str, Controller] = {}
        failures: dict[str, Exception] = {}

        async def open_one(name: str) -> None:
            url, options = self._specs[name]
            async def connecting() -> Controller:
                return await connect(url, **options)

            try:
                opened[name] = await _cancel_once(connecting(), orphan=_close_orphan)
            except Exception as exc:
                failures[name] = self._tag(exc, name)

        try:
            async with anyio.create_task_group() as tg:
                for name in self._specs:
                    tg.start_soon(open_one, name, name=f"tango_aio open {name!r}")
        except BaseException:
            await _close_all(opened)
            raise
        if failures:
            await _close_all(opened)
            raise GroupError(_message("open", failures, len(self._specs)), failures)
        self._controllers = {name: opened[name] for name in self._specs}
        return self

    async def aclose(self) -> None:
        """Close every controller concurrently (each within :data:`CLOSE_TIMEOUT`,
        shielded from cancellation). Raises a :class:`GroupError` if any close failed;
        all were attempted.

        Raises
        ------
        GroupError
            A member failed to close.
        """
        controllers, self._controllers = self._controllers, None
        if not controllers:
            return
        failures = await _close_all(controllers)
        for name, exc in failures.items():
            self._tag(exc, name)
        if failures:
            raise GroupError(_message("close", failures, len(controllers)), failures)

    async def __aenter__(self) -> ControllerGroup:
        return await self.open()

    async def __aexit__(self, exc_type: type[BaseException] | None,
                        exc: BaseException | None, tb: TracebackType | None) -> None:
        if exc is None:
            await self.aclose()
            return
        try:
            await self.aclose()
        except GroupError as close_error:  # do not mask the error that ends the block
            log.warning("closing the group after an error failed: %r", close_error)

    # -- operations -----------------------------------------------------------------------

    async def each(self, func: Callable[[Controller], Awaitable[T]],
                   names: Iterable[str] | None = None, *,
                   fail_fast: bool = False) -> dict[str, T]:
        """Run ``func(controller)`` for every member (or those in ``names``) concurrently
        and return name → result, e.g. ``await group.each(lambda c: c.get("vel"))``.

        Parameters
        ----------
        func
            Called with each member controller; its result is awaited.
        names
            The members to run it for; ``None`` for all of them.
        fail_fast
            Cancel the others at the first failure instead of letting them finish.

        Returns
        -------
        dict[str, T]
            The result of each member, by member name.

        Raises
        ------
        GroupError
            A member's call failed.
        """
        selected = self._select(names)
        return await self._run("each", {name: func for name in selected}, fail_fast)

    async def move_to(self, targets: Mapping[str, Mapping[str, float]], *,
                      timeout: float | None = None, stop_on_cancel: bool = True,
                      fail_fast: bool = False) -> dict[str, dict[str, str]]:
        """Move the named controllers to absolute positions concurrently and wait until
        all arrived: ``await group.move_to({"stage": {"x": 1, "y": 2}, "focus": {"x": 0}})``.

        Returns name → per-axis status letters (see :meth:`Controller.move_to`); a member
        that fails (e.g. :class:`~tango_aio.errors.MoveError`) is reported in a
        :class:`GroupError` after the others have finished. ``timeout`` applies to each
        controller's move (default: computed per controller).

        Parameters
        ----------
        targets
            The target of each axis (axis name to position), by member name.
        timeout
            Seconds each member's move may take; ``None`` for the member's own estimate.
        stop_on_cancel
            Stop a member's axes when its move is cancelled.
        fail_fast
            Cancel (and so stop) the other members' moves at the first failure.

        Returns
        -------
        dict[str, dict[str, str]]
            The status letters of each member's axes, by member name.

        Raises
        ------
        GroupError
            A member's move failed.
        """
        return await self._motion("moa", "move_to", targets, timeout, stop_on_cancel,
                                  fail_fast)

    async def move_by(self, distances: Mapping[str, Mapping[str, float]], *,
                      timeout: float | None = None, stop_on_cancel: bool = True,
                      fail_fast: bool = False) -> dict[str, dict[str, str]]:
        """Move the named controllers by relative distances concurrently; see
        :meth:`move_to`.

        Parameters
        ----------
        distances
            The distance of each axis (axis name to distance), by member name.
        timeout
            Seconds each member's move may take; ``None`` for the member's own estimate.
        stop_on_cancel
            Stop a member's axes when its move is cancelled.
        fail_fast
            Cancel (and so stop) the other members' moves at the first failure.

        Returns
        -------
        dict[str, dict[str, str]]
            The status letters of each member's axes, by member name.

        Raises
        ------
        GroupError
            A member's move failed.
        """
        return await self._motion("mor", "move_by", distances, timeout, stop_on_cancel,
                                  fail_fast)

    async def calibrate(self, names: Iterable[str] | None = None, *,
                        timeout: float | None = None, stop_on_cancel: bool = True,
                        fail_fast: bool = False) -> dict[str, dict[str, str]]:
        """Calibrate (``cal``) every axis of every member (or of those in ``names``)
        concurrently; returns name → status letters.

        Parameters
        ----------
        names
            The members to calibrate; ``None`` for all of them.
        timeout
            Seconds each member's calibration may take; ``None`` for the member's own estimate.
        stop_on_cancel
            Stop a member's axes when its calibration is cancelled.
        fail_fast
            Cancel the others at the first failure.

        Returns
        -------
        dict[str, dict[str, str]]
            The status letters of each member's axes, by member name.

        Raises
        ------
        GroupError
            A member's calibration failed.
        """
        selected = self._select(names)
        return await self._run("calibrate", {
            name: lambda c: c.calibrate(timeout=timeout, stop_on_cancel=stop_on_cancel)
            for name in selected}, fail_fast)

    async def measure_range(self, names: Iterable[str] | None = None, *,
                            timeout: float | None = None, stop_on_cancel: bool = True,
                            fail_fast: bool = False) -> dict[str, dict[str, str]]:
        """Range measure (``rm``) on every member (or on those in ``names``)
        concurrently; returns name → status letters.

        Parameters
        ----------
        names
            The members to measure; ``None`` for all of them.
        timeout
            Seconds each member's range measure may take; ``None`` for the member's own
            estimate.
        stop_on_cancel
            Stop a member's axes when its range measure is cancelled.
        fail_fast
            Cancel the others at the first failure.

        Returns
        -------
        dict[str, dict[str, str]]
            The status letters of each member's axes, by member name.

        Raises
        ------
        GroupError
            A member's range measure failed.
        """
        selected = self._select(names)
        return await self._run("measure_range", {
            name: lambda c: c.measure_range(timeout=timeout, stop_on_cancel=stop_on_cancel)
            for name in selected}, fail_fast)

    async def stop(self, *axes: str, names: Iterable[str] | None = None,
                   wait: bool = True) -> None:
        """Stop the named axes (``a x``; every axis without axes) of every member (or of
        those in ``names``) in parallel; see :meth:`Controller.stop`. Every member is
        attempted even if some fail; the failures are raised as a :class:`GroupError`
        afterwards. Moves of other axes go on.

        Parameters
        ----------
        *axes
            The axis letters to stop; none for every axis.
        names
            The members to stop; ``None`` for all of them.
        wait
            Return only once the stopped axes stand still.

        Raises
        ------
        GroupError
            A member's stop failed.
        """
        selected = self._select(names)
        await self._run("stop", {
            name: lambda c: c.stop(*axes, wait=wait) for name in selected}, False)

    async def abort(self, names: Iterable[str] | None = None, *, soft: bool = False,
                    wait: bool = True) -> None:
        """Stop every member (or those in ``names``) in parallel.

        By default each gets Ctrl+C (see :meth:`Controller.abort`); ``soft=True`` sends
        ``a``. Every member is attempted even if some fail (e.g. a lost connection); the
        failures are raised as a :class:`GroupError` afterwards. Moves being awaited
        raise :class:`~tango_aio.errors.MoveError`.

        Parameters
        ----------
        names
            The members to stop; ``None`` for all of them.
        soft
            Send ``a`` instead of Ctrl+C.
        wait
            Return only once the axes stand still.

        Raises
        ------
        GroupError
            A member's abort failed.
        """
        selected = self._select(names)
        await self._run("abort", {
            name: lambda c: c.abort(soft=soft, wait=wait) for name in selected}, False)

    async def position(self, names: Iterable[str] | None = None
                       ) -> dict[str, dict[str, float]]:
        """name → axis positions of every member (or of those in ``names``).

        Parameters
        ----------
        names
            The members to read; ``None`` for all of them.

        Returns
        -------
        dict[str, dict[str, float]]
            The position of each axis, by member name.

        Raises
        ------
        GroupError
            A member's read failed.
        """
        return await self.each(lambda c: c.position(), names)

    async def status(self, names: Iterable[str] | None = None) -> dict[str, dict[str, str]]:
        """name → ``statusaxis`` letters of every member (or of those in ``names``).

        Parameters
        ----------
        names
            The members to read; ``None`` for all of them.

        Returns
        -------
        dict[str, dict[str, str]]
            The status letter of each axis, by member name.

        Raises
        ------
        GroupError
            A member's read failed.
        """
        return await self.each(lambda c: c.status(), names)

    def events(self, maxsize: int = 256) -> GroupSubscription:
        """Subscribe to the merged events of all members, as :class:`GroupEvent`
        ``(name, event)`` pairs; see :class:`GroupSubscription` (bounded buffer of
        ``maxsize`` events, oldest dropped on overflow).

        Parameters
        ----------
        maxsize
            How many events the subscription holds before it drops the oldest.

        Returns
        -------
        GroupSubscription
            The subscription (an async iterator and context manager).
        """
        members = {name: controller.events(maxsize) for name, controller in self.items()}
        return GroupSubscription(members, maxsize)

    # -- internals ------------------------------------------------------------------------

    def _select(self, names: Iterable[str] | None) -> list[str]:
        if self._controllers is None:
            raise RuntimeError("the ControllerGroup is not open")
        if names is None:
            return list(self._specs)
        if isinstance(names, str):
            names = [names]
        selected = list(dict.fromkeys(names))
        unknown = [name for name in selected if name not in self._specs]
        if unknown:
            raise KeyError(f"no controller named {', '.join(map(repr, unknown))} in the "
                           f"group ({', '.join(map(repr, self._specs))})")
        return selected

    async def _motion(self, instruction: str, op: str,
                      targets: Mapping[str, Mapping[str, float]], timeout: float | None,
                      stop_on_cancel: bool, fail_fast: bool) -> dict[str, dict[str, str]]:
        self._select(targets)
        invalid: dict[str, Exception] = {}
        for name, axes in targets.items():
            try:
                self[name].validate_move(relative=instruction == "mor", **axes)
            except InvalidCommandError as exc:
                invalid[name] = self._tag(exc, name)
        if invalid:
            raise GroupError(f"{op}: invalid input for "
                             f"{', '.join(map(repr, invalid))}; nothing was sent", invalid)

        def call(axes: Mapping[str, float]) -> Callable[[Controller], Awaitable[dict[str, str]]]:
            async def run(controller: Controller) -> dict[str, str]:
                method = controller.move_to if instruction == "moa" else controller.move_by
                return await method(timeout=timeout, stop_on_cancel=stop_on_cancel, unit=None,
                                    **axes)
            return run

        return await self._run(op, {name: call(axes) for name, axes in targets.items()},
                               fail_fast)

    async def _run(self, op: str, calls: Mapping[str, Callable[[Controller], Awaitable[T]]],
                   fail_fast: bool) -> dict[str, T]:
        """Run ``calls`` concurrently; raise a :class:`GroupError` after all finished if
        any failed (with ``fail_fast``, at the first failure, cancelling the others)."""
        results: dict[str, T] = {}
        failures: dict[str, Exception] = {}
        controllers = {name: self[name] for name in calls}

        async def one(name: str, call: Callable[[Controller], Awaitable[T]],
                      scope: anyio.CancelScope) -> None:
            try:
                results[name] = await _cancel_once(call(controllers[name]))
            except Exception as exc:
                failures[name] = self._tag(exc, name)
                if fail_fast:
                    scope.cancel()

        async with anyio.create_task_group() as tg:
            for name, call in calls.items():
                tg.start_soon(one, name, call, tg.cancel_scope, name=f"tango_aio {op} {name!r}")
        ordered = {name: results[name] for name in calls if name in results}
        if failures:
            cancelled = [name for name in calls if name not in results and name not in failures]
            raise GroupError(_message(op, failures, len(calls)), failures, ordered, cancelled)
        return ordered

    def _tag(self, exc: Exception, name: str) -> Exception:
        """Add the note that names the controller ``exc`` belongs to."""
        exc.add_note(f"controller {name!r} ({self._specs[name][0]})")
        return exc


async def _cancel_once(awaitable: Awaitable[T],
                       orphan: Callable[[T], Awaitable[None]] | None = None) -> T:
    """Await ``awaitable`` in its own task, and turn a cancellation into a single
    ``Task.cancel()`` of that task whose clean-up is awaited (shielded, within
    :data:`CANCEL_CLEANUP_TIMEOUT`)."""
    task: asyncio.Future[T] = asyncio.ensure_future(awaitable)
    try:
        return await asyncio.shield(task)
    except asyncio.CancelledError:
        task.cancel()
        with anyio.move_on_after(CANCEL_CLEANUP_TIMEOUT, shield=True):
            await asyncio.wait([task])
            if task.done() and not task.cancelled():
                if task.exception() is not None:
                    log.debug("error while cancelling: %r", task.exception())
                elif orphan is not None:
                    await orphan(task.result())
        raise


async def _close_orphan(controller: Controller) -> None:
    """Close a controller that connected after its group's open was cancelled."""
    try:
        await controller.aclose()
    except Exception:
        log.debug("closing %s after a cancelled open failed", controller.url, exc_info=True)


def _message(op: str, failures: Mapping[str, Exception], total: int) -> str:
    names = ", ".join(repr(name) for name in failures)
    return f"{op} failed on {len(failures)} of {total} controller(s): {names}"


async def _close_all(controllers: Mapping[str, Controller]) -> dict[str, Exception]:
    """Close ``controllers`` concurrently, shielded from cancellation; return failures."""
    failures: dict[str, Exception] = {}

    async def close_one(name: str, controller: Controller) -> None:
        try:
            with anyio.fail_after(CLOSE_TIMEOUT):
                await controller.aclose()
        except Exception as exc:
            log.debug("closing controller %r failed", name, exc_info=True)
            failures[name] = exc

    with anyio.CancelScope(shield=True):
        async with anyio.create_task_group() as tg:
            for name, controller in controllers.items():
                tg.start_soon(close_one, name, controller)
    return failures
