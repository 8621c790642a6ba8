"""The driver's event loop in a thread of its own (:class:`Portal`), and the ``start_*``
calls it runs, which Ctrl+C anywhere stops (:func:`stop_started`)."""

from __future__ import annotations

import concurrent.futures
import contextlib
import os
import queue
import threading
import time
from collections.abc import (
    AsyncIterator,
    Awaitable,
    Callable,
    Iterator,
)
from typing import ParamSpec, TypeVar

import anyio
import anyio.from_thread

P = ParamSpec("P")
R = TypeVar("R")
T = TypeVar("T")

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
        not begun at all if it was cancelled before it could begin."""
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
