"""A controller that restarted behind a live link: noticed and recovered from.

A TANGO that loses its power, or is reset, behind an adapter that stays up (a USB adapter
powered by the host, a serial-to-TCP adapter) leaves the link open. It comes back in
autostatus 1, the power-on mode (L2069, L2085), with its saved settings (L1771-1775) and
its position counters at 0. In autostatus 2 and 4 every set and move then goes unanswered
(the ``OK...`` or the echo the driver waits for never comes, L2099-2117) although the
controller executes it. So the driver reads the mode in force
(:meth:`~tango_aio.link._protocol.TangoProtocol.verify_autostatus`) whenever there is a sign:

* a request got no answer in time in mode 2 or 4 (:func:`timeout_suggests_restart`; in
  modes 0, 1 and 3 a restart leaves every request answered);
* a move that ended short of its target without its completion report
  (:func:`unreported_end_suggests_restart`);
* a completion report the mode in force does not send (:func:`report_suggests_restart`:
  any in mode 0, one with letters in mode 3, which sends a bare CR, L2107-2110);
* the keepalive's periodic read of the mode (``connect(keepalive=...)``).

Choice: the settings are read, not written back. What the session had set and not saved
is reported as changed in the event; writing it back would move on values the user may
no longer want after a restart, and the manual's own recipe after ``reset`` is to poll and
start over (L1837-1857).
"""

from __future__ import annotations

import asyncio
import dataclasses
import functools
import logging
from collections.abc import Awaitable, Callable, Mapping
from typing import Any, Protocol

from ..catalog import Command, Form, build
from ..errors import ControllerTimeoutError, TangoError
from ..events import ControllerRestarted
from ..moves import MoveTiming

__all__ = ["RestartWatch", "Restartable", "changed_settings", "report_suggests_restart",
           "settings_of", "timeout_suggests_restart", "unreported_end_suggests_restart"]

log = logging.getLogger("tango_aio")

#: Times a suspected restart's mode read is tried when it times out.
CHECK_ATTEMPTS = 3


def report_suggests_restart(mode: int, letters: bool) -> bool:
    """Whether a completion report (``letters``: with status letters, not a bare CR) is
    one the driver's mode ``mode`` never sends, so the controller is in another mode: in
    mode 0 none comes (L2079-2081), in mode 3 a bare CR (L2107-2110)."""
    return mode == 0 or (mode == 3 and letters)


def timeout_suggests_restart(mode: int) -> bool:
    """Whether a request that got no answer in time, in the driver's mode ``mode``, may
    be a restart: in modes 2 and 4 the acknowledgement or echo the driver waits for
    (L2099-2103, L2117) never comes from a controller back in mode 1."""
    return mode in (2, 4)


def unreported_end_suggests_restart(mode: int) -> bool:
    """Whether a move that ended short of its target without the completion report the
    driver's mode ``mode`` sends may be a restart, which loses the move and its report
    (the power-on mode 1 and counters 0, L2062, L1837-1857). In modes 2 and 4 a
    controller back in mode 1 leaves every later set unanswered (L2099-2103, L2117), and
    in mode 3 it sends letters where the driver expects a bare CR (L2107-2110): read the
    mode now, before the next line meets it. Mode 0 sends no report (L2079-2081); in
    mode 1, the power-on mode, a read cannot tell."""
    return mode in (2, 3, 4)


def settings_of(timing: MoveTiming) -> dict[str, Any]:
    """The cached settings' values by field name (lists copied)."""
    return {f.name: _copied(getattr(timing, f.name)) for f in dataclasses.fields(MoveTiming)}


def changed_settings(before: Mapping[str, Any], after: Mapping[str, Any]
                     ) -> dict[str, tuple[object, object]]:
    """The settings whose value differs."""
    return {name: (before[name], after.get(name)) for name in before
            if before[name] != after.get(name)}


def _copied(value: Any) -> Any:
    return list(value) if isinstance(value, list) else value


class Restartable(Protocol):
    """What the watch needs of a protocol (:class:`~tango_aio.link._protocol.TangoProtocol`)."""

    on_unanswered: Callable[[], None] | None
    on_restored: Callable[[int, int], None] | None

    @property
    def autostatus(self) -> int:
        """The mode the driver has in force."""

    def hold_for_check(self) -> None:
        """Hold the lines submitted from now on until the next read of the mode."""

    def release_check_hold(self) -> None:
        """End a hold of :meth:`hold_for_check` that no read of the mode took over."""

    async def verify_autostatus(self, *, timeout: float | None) -> bool:
        """Read the mode in force; restore the driver's if it differs."""

    async def execute(self, command: Command, *, timeout: float | None,
                      check: bool = True) -> Any:
        """Write a set line (here ``!autostatus n``) and wait until it is confirmed."""


class RestartWatch:
    """Reads the mode in force when something suggests a restart, and recovers from one:
    see the module's docstring."""

    def __init__(self, reload: Callable[[], Awaitable[tuple[dict[str, Any], dict[str, Any]]]],
                 publish: Callable[[ControllerRestarted], None], reply_timeout: float) -> None:
        self._reload = reload
        self._publish = publish
        self._timeout = reply_timeout
        self._protocol: Restartable | None = None
        self._tasks: set[asyncio.Task[None]] = set()
        self._checking: asyncio.Task[None] | None = None
        #: Restarts recovered from so far.
        self.restarts = 0

    def attach(self, protocol: Restartable) -> None:
        """Watch ``protocol`` (the link in use; a reconnect attaches the new one)."""
        self._protocol = protocol
        protocol.on_unanswered = self._unanswered
        protocol.on_restored = self.restored

    def suspect(self) -> None:
        """Something suggests a restart: read the mode in force (once at a time). The
        lines submitted from now on wait for that read (the call after the one that met
        the restart goes out in the driver's mode)."""
        if self._protocol is None or (self._checking is not None
                                      and not self._checking.done()):
            return
        protocol = self._protocol
        protocol.hold_for_check()
        self._checking = self._spawn(self._check(protocol))
        # Whatever ends the check (cancelled before it ran, too), no hold is left behind.
        self._checking.add_done_callback(functools.partial(self._checked, protocol))

    def _checked(self, protocol: Restartable, task: asyncio.Task[None]) -> None:
        if task is self._checking:  # (a newer check takes over a hold still standing)
            protocol.release_check_hold()

    def _unanswered(self) -> None:
        if self._protocol is not None and \
                timeout_suggests_restart(self._protocol.autostatus):
            self.suspect()

    def restored(self, found: int, autostatus: int) -> None:
        """The protocol found another mode in force and selected its own again."""
        log.warning("the controller restarted (autostatus %d, the driver had %d); "
                    "autostatus %d restored, reading the settings again",
                    found, autostatus, autostatus)
        self._spawn(self._recover(found, autostatus))

    def close(self) -> None:
        """Stop: cancel the checks under way."""
        for task in list(self._tasks):
            task.cancel()

    def _spawn(self, coroutine: Awaitable[None]) -> asyncio.Task[None]:
        task = asyncio.ensure_future(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _check(self, protocol: Restartable) -> None:
        wanted = protocol.autostatus  # the driver's mode, before a read adopts another
        for _ in range(CHECK_ATTEMPTS):
            try:
                if protocol.autostatus == wanted:
                    await protocol.verify_autostatus(timeout=self._timeout)
                else:
                    # An earlier attempt found (and adopted) another mode, but selecting
                    # the driver's failed: select it now.
                    found = protocol.autostatus
                    await protocol.execute(build("autostatus", wanted, form=Form.SET),
                                           timeout=self._timeout)
                    self.restored(found, wanted)
                return
            except ControllerTimeoutError as exc:
                # Lines written before went unanswered too (in modes 2 and 4, after a
                # restart, a stop's acknowledgement or echo never comes): once they
                # timed out, the mode can be read and set.
                log.debug("reading or selecting the mode timed out: %s", exc)
            except TangoError as exc:  # the next sign tries again
                log.debug("reading or selecting the mode failed: %r", exc)
                return

    async def _recover(self, found: int, autostatus: int) -> None:
        try:
            before, after = await self._reload()
        except TangoError as exc:
            log.warning("after the restart, the settings could not be read again: %s", exc)
            before = after = {}
        self.restarts += 1
        self._publish(ControllerRestarted(found, autostatus, changed_settings(before, after)))
