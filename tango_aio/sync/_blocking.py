"""The blocking descriptors (a method made blocking, ``start_<name>``) and the base of the
blocking classes, each the twin of an async object on a :class:`~tango_aio.sync.Portal`."""

from __future__ import annotations

import concurrent.futures
import functools
import inspect
import re
from collections.abc import (
    Callable,
    Coroutine,
)
from typing import Any, Concatenate, Generic, ParamSpec, TypeVar, overload

from ._portal import Portal, stop_started

P = ParamSpec("P")
R = TypeVar("R")
A = TypeVar("A")
#: The async object a blocking class wraps: a method of a base class of it binds too.
A_co = TypeVar("A_co", covariant=True)


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
        the method callable for introspection (documentation tools)."""
        return self.__get__(obj, type(obj))(*args, **kwargs)


def _without_returns(doc: str | None) -> str:
    """``doc`` dedented, so that its numpydoc sections still parse after the line put
    before it, and without its Returns section: a ``start_*`` call returns the future."""
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
        (a started move that failed must not pass for an idle stage)."""
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

    def _per_axis(self, name: str, /, *args: Any, axis: str | None) -> Any:
        """Run the async per-axis read ``name`` (one value with ``axis``, else a dict by
        axis) in the driver's thread."""
        return self._portal.call(getattr(self.aio, name), *args, axis=axis)

    @property
    def portal(self) -> Portal:
        """The thread running the driver's event loop."""
        return self._portal
