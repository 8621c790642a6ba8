"""A virtual clock for asyncio tests: the event loop's time jumps ahead whenever nothing
can happen before its next timer (trio's ``MockClock`` with ``autojump_threshold=0`` is
the model).

:class:`VirtualClockLoop` is an ordinary selector event loop whose :meth:`time` is the
monotonic clock plus an offset. When the loop is about to wait (no callback is ready), it
first looks whether a file descriptor is ready; if not, and if nothing outside the loop
can wake it, it adds the wait to the offset instead of sleeping: the next timer is due at
once. Everything the loop runs sees the same clock: the driver's reply and move timeouts,
its polls, and the in-process emulator (``sim://``), whose wire and controller read the
running loop's time (``tango_aio.sim.clock.host_now``). A move of 2 s at the emulator's
speed then takes the few loop turns that its status reads and reports take, and the
verdicts are the ones the real clock gives, because both ends wait on the same clock.

Only the loop's own work can be fast-forwarded. The loop stops jumping, for good, the
first time something outside it may wake it up: a file descriptor other than its own
wake-up pipe is watched (a socket, a pty, a subprocess' pipes), or another thread hands it
work (``call_soon_threadsafe``, ``run_in_executor``). From then on it waits in real time,
as a plain loop does. While a thread that was not running when the loop was made is alive
(a worker of ``asyncio.to_thread`` or anyio, a test's own ``threading.Thread``), the loop
does not jump either: that thread may be about to call back.

Tests take it with ``@pytest.mark.virtual_clock`` (or a module's ``pytestmark``); the
marker chooses this loop in ``conftest.py`` (``pytest_asyncio_loop_factories``). Under
``TANGO_AIO_TEST_LOOP=uvloop`` the marker is ignored: those runs keep real time.
"""

from __future__ import annotations

import asyncio
import selectors
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor
from contextvars import Context
from typing import TypeVar, TypeVarTuple

__all__ = ["VirtualClockLoop"]

_T = TypeVar("_T")
_Ts = TypeVarTuple("_Ts")


class _JumpingSelector(selectors.DefaultSelector):
    """The default selector; a wait that nothing can end moves the loop's clock instead."""

    loop: VirtualClockLoop | None = None

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        loop = self.loop
        if loop is None or timeout is None or timeout <= 0 or not loop.may_jump():
            return super().select(timeout)
        ready = super().select(0)
        if not ready:
            loop.advance(timeout)
        return ready


class VirtualClockLoop(asyncio.SelectorEventLoop):
    """An event loop whose clock jumps over waits that only its own timers can end."""

    def __init__(self) -> None:
        selector = _JumpingSelector()
        super().__init__(selector)
        self._offset = 0.0
        self._outside = False
        selector.loop = self
        self._wakeup_fds = len(selector.get_map())  # the loop's own wake-up pipe
        self._threads = {thread.ident for thread in threading.enumerate()}

    def time(self) -> float:
        return time.monotonic() + self._offset

    @property
    def jumped(self) -> float:
        """Seconds the clock has jumped so far."""
        return self._offset

    def advance(self, seconds: float) -> None:
        """Move the clock ``seconds`` ahead (``seconds`` >= 0)."""
        if seconds < 0:
            raise ValueError(f"the clock only moves forward, not by {seconds!r}")
        self._offset += seconds

    def may_jump(self) -> bool:
        """Whether only the loop's own timers can end a wait (see the module docstring)."""
        if self._outside:
            return False
        if len(self._selector.get_map()) > self._wakeup_fds:  # type: ignore[attr-defined]
            self._outside = True
            return False
        return all(thread.ident in self._threads for thread in threading.enumerate())

    def call_soon_threadsafe(self, callback: Callable[[*_Ts], object],
                             *args: *_Ts, context: Context | None = None
                             ) -> asyncio.Handle:
        self._outside = True
        return super().call_soon_threadsafe(callback, *args, context=context)

    def run_in_executor(self, executor: Executor | None,
                        func: Callable[[*_Ts], _T], *args: *_Ts
                        ) -> asyncio.Future[_T]:
        self._outside = True
        return super().run_in_executor(executor, func, *args)
