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
import concurrent.futures
import contextlib
import functools
import inspect
import os
import queue
import re
import threading
import time
import weakref
from collections.abc import (
    AsyncIterator,
    Awaitable,
    Callable,
    Coroutine,
    Iterable,
    Iterator,
    Mapping,
)
from types import TracebackType
from typing import Any, Concatenate, Generic, ParamSpec, TypeVar, overload

import anyio
import anyio.from_thread

from . import controller as _connection
from .controller import Controller as AsyncController
from .controller import Identity
from .events import InputsChanged, JoystickMoved, PositionUpdate, Subscription, TangoEvent
from .families import IO as AsyncIO
from .families import ClosedLoop as AsyncClosedLoop
from .families import Encoders as AsyncEncoders
from .families import Family
from .families import Joystick as AsyncJoystick
from .families import Snapshots as AsyncSnapshots
from .families import Triggers as AsyncTriggers
from .group import ControllerGroup as AsyncGroup
from .group import ControllerSpec, GroupEvent, GroupSubscription

__all__ = ["IO", "STOP_WAIT", "ClosedLoop", "Controller", "ControllerGroup", "Encoders",
           "Joystick", "Portal", "Snapshots", "Triggers", "connect", "family_twin",
           "stop_started"]

P = ParamSpec("P")
R = TypeVar("R")
T = TypeVar("T")
A = TypeVar("A")
#: The async object a blocking class wraps: a method of a base class of it binds too.
A_co = TypeVar("A_co", covariant=True)

#: Longest wait, after Ctrl+C, for the cancelled call to finish (axes stopped), seconds.
STOP_WAIT = 15.0


class Portal:
    """The driver's event loop in a thread of its own (an anyio blocking portal).

    The loop is asyncio; it is uvloop's when the environment variable
    ``TANGO_AIO_LOOP=uvloop`` is set and uvloop is installed (``tango-aio[uvloop]``).
    The thread is a daemon thread, so a script that forgets ``close()`` still exits: what
    is still open is closed at interpreter exit (:mod:`atexit`), while the loop runs.
    """

    def __init__(self) -> None:
        options = {"use_uvloop": True} if os.environ.get("TANGO_AIO_LOOP") == "uvloop" else {}
        handed: queue.Queue[anyio.from_thread.BlockingPortal | BaseException] = queue.Queue()

        async def serve() -> None:
            async with anyio.from_thread.BlockingPortal() as portal:
                handed.put(portal)
                await portal.sleep_until_stopped()

        def run() -> None:
            try:
                anyio.run(serve, backend="asyncio", backend_options=options)
            except BaseException as exc:  # e.g. uvloop missing: tell the caller
                handed.put(exc)

        self._thread = threading.Thread(target=run, name="tango_aio driver loop",
                                        daemon=True)
        self._thread.start()
        got = handed.get()
        if isinstance(got, BaseException):
            raise got
        self.portal = got

    def call(self, func: Callable[P, Awaitable[R]], *args: P.args, **kwargs: P.kwargs) -> R:
        """Run ``func(*args, **kwargs)`` in the driver's thread and wait for its result.

        On :class:`KeyboardInterrupt` the call is cancelled there, and the interrupt is
        re-raised once its clean-up (e.g. stopping the axes) is done.

        Parameters
        ----------
        func
            The coroutine function to run in the driver's thread.
        *args, **kwargs
            Its arguments.

        Returns
        -------
        R
            What ``func`` returned.

        Raises
        ------
        KeyboardInterrupt
            Re-raised after the call has been cancelled and cleaned up.
        """
        finished = threading.Event()
        state = threading.Lock()
        interrupted = False
        scopes: list[anyio.CancelScope] = []  # the call's scope, once it has begun

        async def run() -> R:
            with anyio.CancelScope() as scope:
                with state:
                    if interrupted:  # Ctrl+C came before the call began: do not begin it
                        raise anyio.get_cancelled_exc_class()
                    scopes.append(scope)
                try:
                    return await func(*args, **kwargs)
                finally:
                    finished.set()
            raise anyio.get_cancelled_exc_class()  # cancelled after Ctrl+C (below)

        try:
            # Ctrl+C may land while start_task_soon still waits for the task to be spawned,
            # when the call may have begun already (a move written): hence the scope of
            # the call's own, which is cancelled below whether or not a future came back.
            return self.portal.start_task_soon(run).result()
        except KeyboardInterrupt:
            with state:
                interrupted = True
                began = scopes[0] if scopes else None
            if began is not None:  # cancel it there and wait for its clean-up (axes stopped)
                self.portal.call(began.cancel)
                finished.wait(STOP_WAIT)
            stop_started()  # and what start_* calls started (moves this program began)
            raise

    def start(self, func: Callable[P, Awaitable[R]], *args: P.args, **kwargs: P.kwargs
              ) -> concurrent.futures.Future[R]:
        """Start ``func(*args, **kwargs)`` in the driver's thread; return its future. The
        call is recorded until it has finished: Ctrl+C in any blocking call cancels it
        (:func:`stop_started`), as does Ctrl+C while it is being started.

        Parameters
        ----------
        func
            The coroutine function to start in the driver's thread.
        *args, **kwargs
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            The future of ``func``'s result; cancelling it cancels the call.

        Raises
        ------
        KeyboardInterrupt
            Re-raised after every started call has been stopped.
        """
        started = _Started(self)
        try:
            return self.portal.start_task_soon(started.wrap(func, *args, **kwargs))
        except KeyboardInterrupt:
            stop_started()
            raise
        except BaseException:
            started.forget()  # never started (e.g. the portal has stopped)
            raise

    def iterate(self, source: AsyncIterator[T]) -> Iterator[T]:
        """Iterate an async iterator of the driver's thread from this thread; leaving the
        loop early (``break``, an exception) closes it there.

        Parameters
        ----------
        source
            An async iterator that belongs to the driver's thread.

        Yields
        ------
        T
            Each item of ``source``, in order.
        """
        try:
            while True:
                try:
                    yield self.call(_anext, source)
                except StopAsyncIteration:
                    return
        finally:
            close = getattr(source, "aclose", None)
            if close is not None:
                with contextlib.suppress(Exception):
                    self.call(close)

    def stop(self) -> None:
        """Stop the loop and join its thread."""
        if self._thread.is_alive():
            with contextlib.suppress(RuntimeError):  # already stopping
                self.portal.call(self.portal.stop)
            self._thread.join()


#: The ``start_*`` calls of this process whose task has not finished (see
#: :func:`stop_started`).
_RUNNING: set[_Started] = set()
_RUNNING_LOCK = threading.Lock()


class _Started:
    """One call started with :meth:`Portal.start`: what its task tells the caller's
    thread (whether it began, its cancel scope, when its clean-up is over)."""

    def __init__(self, portal: Portal) -> None:
        self._portal = portal
        self._lock = threading.Lock()
        self._interrupted = False
        self._scope: anyio.CancelScope | None = None
        self.finished = threading.Event()
        """Set once the task has ended, its clean-up (stopping the axes) included."""
        with _RUNNING_LOCK:
            _RUNNING.add(self)

    def wrap(self, func: Callable[P, Awaitable[R]], *args: P.args, **kwargs: P.kwargs
             ) -> Callable[[], Awaitable[R]]:
        """The task to start: ``func(*args, **kwargs)`` in a cancel scope of its own,
        not begun at all if it was cancelled before it could begin.

        Returns
        -------
        Callable
            A coroutine function without arguments, to hand to the portal.
        """
        async def run() -> R:
            try:
                with anyio.CancelScope() as scope:
                    with self._lock:
                        if self._interrupted:
                            raise anyio.get_cancelled_exc_class()
                        self._scope = scope
                    return await func(*args, **kwargs)
                raise anyio.get_cancelled_exc_class()  # cancelled by cancel() below
            finally:
                self.forget()
        return run

    def forget(self) -> None:
        """The task was never started: nothing to stop or wait for."""
        self.finished.set()
        with _RUNNING_LOCK:
            _RUNNING.discard(self)

    def cancel(self) -> None:
        """Cancel the task from another thread (it stops its move, as a cancelled
        awaited move does); returns once the cancellation is handed over."""
        with self._lock:
            self._interrupted = True
            scope = self._scope
        if scope is not None and not self.finished.is_set():
            with contextlib.suppress(RuntimeError):  # the portal has stopped: nothing runs
                self._portal.portal.call(scope.cancel)


def stop_started() -> None:
    """Cancel every ``start_*`` call of this process still running (Ctrl+C landed in a
    blocking call) and wait, at most :data:`STOP_WAIT` seconds, until they have
    ended: a started move stops its axes (unless ``stop_on_cancel=False``)."""
    with _RUNNING_LOCK:
        running = list(_RUNNING)
    for started in running:
        started.cancel()
    deadline = time.monotonic() + STOP_WAIT
    for started in running:
        started.finished.wait(max(0.0, deadline - time.monotonic()))


async def _anext(source: AsyncIterator[T]) -> T:
    return await source.__anext__()


class _Blocking(Generic[A, P, R]):
    """A blocking method made from the async method ``method`` of the wrapped object:
    same parameters, same docstring, same return type."""

    def __init__(self, method: Callable[Concatenate[A, P], Coroutine[Any, Any, R]]) -> None:
        self._method = method
        self.__doc__ = method.__doc__
        self.__wrapped__ = method

    @overload
    def __get__(self, obj: None, owner: type[Any]) -> _Blocking[A, P, R]: ...
    @overload
    def __get__(self, obj: _Wrapper[A], owner: type[Any]) -> Callable[P, R]: ...
    def __get__(self, obj: _Wrapper[A] | None, owner: type[Any]
                ) -> _Blocking[A, P, R] | Callable[P, R]:
        if obj is None:
            return self
        bound: Callable[P, Coroutine[Any, Any, R]] = getattr(obj.aio, self._method.__name__)

        @functools.wraps(bound)
        def call(*args: P.args, **kwargs: P.kwargs) -> R:
            return obj._portal.call(bound, *args, **kwargs)

        return call

    def __call__(self, obj: _Wrapper[A], /, *args: P.args, **kwargs: P.kwargs) -> R:
        """Call through the class (``Controller.move_to(tango, x=1)``); this also makes
        the method callable for introspection (documentation tools).

        Returns
        -------
        R
            What the async method returned.
        """
        return self.__get__(obj, type(obj))(*args, **kwargs)


def _without_returns(doc: str | None) -> str:
    """``doc`` dedented, so that its numpydoc sections still parse after the line put
    before it, and without its Returns section: a ``start_*`` call returns the future.

    Parameters
    ----------
    doc
        The async method's docstring.

    Returns
    -------
    str
        The text to follow that line.
    """
    text = inspect.cleandoc(doc or "")
    return re.sub(r"(?ms)^Returns\n-+\n.*?(?=^\S[^\n]*\n-+\n|\Z)", "", text).rstrip()


class _Starter(Generic[A, P, R]):
    """``start_<name>``: start the async method ``method`` and return a future at once."""

    def __init__(self, method: Callable[Concatenate[A, P], Coroutine[Any, Any, R]]) -> None:
        self._method = method
        self.__doc__ = (f"Start :meth:`{method.__name__}` and return at once a "
                        ":class:`concurrent.futures.Future` of its result (cancelling the "
                        f"future cancels it).\n\n{_without_returns(method.__doc__)}")

    @overload
    def __get__(self, obj: None, owner: type[Any]) -> _Starter[A, P, R]: ...
    @overload
    def __get__(self, obj: _Wrapper[A], owner: type[Any]
                ) -> Callable[P, concurrent.futures.Future[R]]: ...
    def __get__(self, obj: _Wrapper[A] | None, owner: type[Any]
                ) -> _Starter[A, P, R] | Callable[P, concurrent.futures.Future[R]]:
        if obj is None:
            return self
        bound: Callable[P, Coroutine[Any, Any, R]] = getattr(obj.aio, self._method.__name__)

        @functools.wraps(bound)
        def start(*args: P.args, **kwargs: P.kwargs) -> concurrent.futures.Future[R]:
            future = obj._portal.start(bound, *args, **kwargs)
            obj._started.append(future)
            return future

        start.__doc__ = self.__doc__
        return start


#: Blocking objects not closed yet; closed at interpreter exit.
_OPEN: weakref.WeakSet[Controller | ControllerGroup] = weakref.WeakSet()


@atexit.register
def _close_open() -> None:
    for wrapper in list(_OPEN):
        with contextlib.suppress(Exception):
            wrapper.close()


class _Wrapper(Generic[A_co]):
    """Base of the blocking classes: the async object and the portal it runs on."""

    def __init__(self, aio: A_co, portal: Portal, *, owns_portal: bool) -> None:
        self.aio = aio
        """The async object underneath (use it from the driver's thread only)."""
        self._portal = portal
        self._owns_portal = owns_portal
        #: Futures of ``start_*`` calls not yet waited for by ``wait_idle()``.
        self._started: list[concurrent.futures.Future[Any]] = []

    def _join_started(self) -> None:
        """Wait for every ``start_*`` call so far; raise the first one's error, if any
        (a started move that failed must not pass for an idle stage).

        Raises
        ------
        KeyboardInterrupt
            Re-raised after the started moves have been stopped.
        BaseException
            The first error a started call ended with.
        """
        started = list(self._started)
        try:
            concurrent.futures.wait(started)
        except KeyboardInterrupt:
            stop_started()  # Ctrl+C while waiting: the started moves stop
            raise
        self._started = [f for f in self._started if f not in started]
        for future in started:
            if not future.cancelled() and future.exception() is not None:
                raise future.exception()  # type: ignore[misc]

    @property
    def portal(self) -> Portal:
        """The thread running the driver's event loop."""
        return self._portal


def _passing(name: str) -> Callable[..., Any]:
    """A method of a blocking twin that calls the async object's plain method ``name``."""
    def call(self: _Wrapper[Any], *args: Any, **kwargs: Any) -> Any:
        return getattr(self.aio, name)(*args, **kwargs)

    call.__name__ = name
    return call


#: The blocking twin of each family class made so far.
_TWINS: dict[str, type[_Wrapper[Any]]] = {}


def family_twin(cls: type[Family]) -> type[_Wrapper[Any]]:
    """The blocking twin of a family class (:class:`tango_aio.families.Family`): each of
    its public async methods made blocking by the same descriptor as the controller's.

    Parameters
    ----------
    cls
        The async family class (``type(tango.settings)``).

    Returns
    -------
    type
        A class whose instances wrap one family object: ``twin(family, portal,
        owns_portal=False)``.
    """
    key = f"{cls.__module__}.{cls.__qualname__}"
    if key in _TWINS:
        return _TWINS[key]
    members: dict[str, Any] = {
        "__doc__": f"The blocking form of :class:`tango_aio.families.{cls.__name__}`: "
                   "each method blocks until the driver's thread has run it.",
        "__module__": __name__, "__qualname__": cls.__name__}
    for name in dir(cls):
        member = getattr(cls, name)
        if name.startswith("_") or not inspect.isfunction(member):
            continue
        # A plain method (Settings.check) reads only what the family holds: it runs in
        # the caller's thread, as validate_move does.
        members[name] = _Blocking(member) if inspect.iscoroutinefunction(member) \
            else _passing(name)
    twin: type[_Wrapper[Any]] = type(cls.__name__, (_Wrapper,), members)
    _TWINS[key] = twin
    return twin


class _Family(_Wrapper[A]):
    """A blocking family: its own methods are declared; any other coroutine method of
    the async family (the generated typed access, ``tango.io.set_anamode(...)``) is
    made blocking when first looked up."""

    def __getattr__(self, name: str) -> Any:
        if name.startswith("_") or name == "aio":
            raise AttributeError(name)
        method = getattr(self.aio, name)
        if not inspect.iscoroutinefunction(method):
            raise AttributeError(f"{type(self).__name__} has no blocking {name!r}")

        @functools.wraps(method)
        def call(*args: Any, **kwargs: Any) -> Any:
            return self._portal.call(method, *args, **kwargs)

        return call

    def __dir__(self) -> list[str]:
        return sorted({*super().__dir__(), *(
            name for name in dir(self.aio) if not name.startswith("_")
            and inspect.iscoroutinefunction(getattr(self.aio, name)))})


class Joystick(_Family[AsyncJoystick]):
    """The blocking twin of :class:`tango_aio.families.Joystick` (``tango.joystick``)."""

    enable = _Blocking(AsyncJoystick.enable)
    disable = _Blocking(AsyncJoystick.disable)
    is_enabled = _Blocking(AsyncJoystick.is_enabled)


class IO(_Family[AsyncIO]):
    """The blocking twin of :class:`tango_aio.families.IO` (``tango.io``)."""

    set_shutter = _Blocking(AsyncIO.set_shutter)
    shutter = _Blocking(AsyncIO.shutter)
    flash = _Blocking(AsyncIO.flash)
    set_analog_out = _Blocking(AsyncIO.set_analog_out)
    analog_out = _Blocking(AsyncIO.analog_out)
    analog_in = _Blocking(AsyncIO.analog_in)
    digital_in = _Blocking(AsyncIO.digital_in)
    set_digital_out = _Blocking(AsyncIO.set_digital_out)
    digital_out = _Blocking(AsyncIO.digital_out)

    def watch_inputs(self, interval: float = 0.1) -> Iterator[InputsChanged | JoystickMoved]:
        """Blocking iterator over :meth:`tango_aio.families.IO.watch_inputs`.

        Parameters
        ----------
        interval
            Seconds between two reads.

        Returns
        -------
        Iterator[InputsChanged | JoystickMoved]
            What changed, read in the driver's thread.
        """
        return self._portal.iterate(self.aio.watch_inputs(interval))


class Encoders(_Family[AsyncEncoders]):
    """The blocking twin of :class:`tango_aio.families.Encoders` (``tango.encoders``)."""

    mask = _Blocking(AsyncEncoders.mask)
    set_mask = _Blocking(AsyncEncoders.set_mask)
    active = _Blocking(AsyncEncoders.active)
    set_position_source = _Blocking(AsyncEncoders.set_position_source)
    position_error = _Blocking(AsyncEncoders.position_error)


class ClosedLoop(_Family[AsyncClosedLoop]):
    """The blocking twin of :class:`tango_aio.families.ClosedLoop` (``tango.closed_loop``)."""

    enable = _Blocking(AsyncClosedLoop.enable)
    mode = _Blocking(AsyncClosedLoop.mode)
    settle = _Blocking(AsyncClosedLoop.settle)


class Triggers(_Family[AsyncTriggers]):
    """The blocking twin of :class:`tango_aio.families.Triggers` (``tango.triggers``)."""

    read_config = _Blocking(AsyncTriggers.read_config)
    write_config = _Blocking(AsyncTriggers.write_config)
    enabled = _Blocking(AsyncTriggers.enabled)
    set_enabled = _Blocking(AsyncTriggers.set_enabled)
    count = _Blocking(AsyncTriggers.count)
    set_count = _Blocking(AsyncTriggers.set_count)
    fire = _Blocking(AsyncTriggers.fire)
    upload_positions = _Blocking(AsyncTriggers.upload_positions)
    read_positions = _Blocking(AsyncTriggers.read_positions)
    set_range = _Blocking(AsyncTriggers.set_range)


class Snapshots(_Family[AsyncSnapshots]):
    """The blocking twin of :class:`tango_aio.families.Snapshots` (``tango.snapshots``)."""

    read_config = _Blocking(AsyncSnapshots.read_config)
    write_config = _Blocking(AsyncSnapshots.write_config)
    count = _Blocking(AsyncSnapshots.count)
    upload_positions = _Blocking(AsyncSnapshots.upload_positions)
    read_positions = _Blocking(AsyncSnapshots.read_positions)


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
    def settings(self) -> Any:
        """The blocking twin of :attr:`tango_aio.Controller.settings`: every setting by
        name, snapshot, diff, restore, save (each method blocks)."""
        return family_twin(type(self.aio.settings))(self.aio.settings, self._portal,
                                                    owns_portal=False)

    @functools.cached_property
    def info(self) -> Any:
        """The blocking twin of :attr:`tango_aio.Controller.info` (each method blocks)."""
        return family_twin(type(self.aio.info))(self.aio.info, self._portal,
                                                owns_portal=False)

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
    and ``inspect.signature``), keeping its own return type and docstring.

    Parameters
    ----------
    source
        The function whose parameters the decorated function shows.

    Returns
    -------
    Callable
        The decorator.
    """
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
