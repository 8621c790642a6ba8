"""A virtual clock for asyncio tests: the event loop's time stands still while the loop
works and jumps ahead whenever nothing can happen before its next timer (trio's
``MockClock``, with its default ``rate=0`` and ``autojump_threshold=0``, is the model).

:class:`VirtualClockLoop` is an ordinary selector event loop whose :meth:`time` is a
number of its own. When the loop is about to wait (no callback is ready), it first looks
whether a file descriptor is ready; if not, and if nothing outside the loop can wake it,
it moves its clock to the next timer instead of sleeping. Everything the loop runs sees
the same clock: the driver's reply and move timeouts, its polls, and the in-process
emulator (``sim://``), whose wire and controller read the running loop's time
(``tango_aio.sim.clock.host_now``). A move of 2 s at the emulator's speed then takes the
few loop turns that its status reads and reports take, and the verdicts are the ones the
real clock gives, because both ends wait on the same clock. Since the clock does not move
while the loop computes, a loaded machine (a slow turn of the loop) cannot make a timer
expire before the bytes it waits for: such a test runs the same on any machine.

Only the loop's own work can be fast-forwarded. While a thread that was not running when
the loop was made is alive (a worker of anyio, a test's own ``threading.Thread``), the
loop waits in real time and its clock follows the waits: that thread may be about to
call back. For good, from the first time a file descriptor other than its own wake-up
pipe is watched (a socket, a pty, a subprocess' pipes) or another thread hands it work
(``call_soon_threadsafe``, ``run_in_executor``), the clock is the monotonic clock again
(plus what it had jumped), as on a plain loop.

Tests take it with ``@pytest.mark.virtual_clock`` (or a module's ``pytestmark``); the
marker chooses this loop in ``conftest.py`` (``pytest_asyncio_loop_factories``). Under
``TANGO_AIO_TEST_LOOP=uvloop`` the marker is ignored: those runs keep real time. Code
under test that measures time with ``time.monotonic()`` next to the loop's timers (the
field probe's move timing) does not see the jumps: its tests keep the real clock.
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
        if loop is None or loop.real or (timeout is not None and timeout <= 0):
            return super().select(timeout)
        if timeout is not None and loop.may_jump():
            ready = super().select(0)
            if not ready:
                loop.advance(timeout)
            return ready
        started = time.monotonic()  # something outside may end the wait: a real one
        try:
            return super().select(timeout)
        finally:
            loop.waited(time.monotonic() - started)


class VirtualClockLoop(asyncio.SelectorEventLoop):
    """An event loop whose clock jumps over waits that only its own timers can end."""

    def __init__(self) -> None:
        selector = _JumpingSelector()
        super().__init__(selector)
        self._now = time.monotonic()
        self._jumped = 0.0
        self._offset = 0.0
        self.real = False
        """True once the clock is the monotonic clock again (see the module docstring)."""
        selector.loop = self
        self._wakeup_fds = len(selector.get_map())  # the loop's own wake-up pipe
        self._threads = {thread.ident for thread in threading.enumerate()}

    def time(self) -> float:
        if self.real:
            return time.monotonic() + self._offset
        return self._now

    @property
    def jumped(self) -> float:
        """Seconds the clock has jumped so far."""
        return self._jumped

    def advance(self, seconds: float) -> None:
        """Move the clock ``seconds`` ahead (``seconds`` >= 0)."""
        if seconds < 0:
            raise ValueError(f"the clock only moves forward, not by {seconds!r}")
        self._now += seconds
        self._jumped += seconds

    def waited(self, seconds: float) -> None:
        """The loop waited ``seconds`` of real time: its clock follows."""
        if not self.real:
            self._now += seconds

    def may_jump(self) -> bool:
        """Whether only the loop's own timers can end a wait (see the module docstring)."""
        if len(self._selector.get_map()) > self._wakeup_fds:  # type: ignore[attr-defined]
            self._go_real()
            return False
        return all(thread.ident in self._threads for thread in threading.enumerate())

    def _go_real(self) -> None:
        if not self.real:
            self._offset = self._now - time.monotonic()
            self.real = True

    def call_soon_threadsafe(self, callback: Callable[[*_Ts], object],
                             *args: *_Ts, context: Context | None = None
                             ) -> asyncio.Handle:
        self._go_real()
        return super().call_soon_threadsafe(callback, *args, context=context)

    def run_in_executor(self, executor: Executor | None,
                        func: Callable[[*_Ts], _T], *args: *_Ts
                        ) -> asyncio.Future[_T]:
        self._go_real()
        return super().run_in_executor(executor, func, *args)
