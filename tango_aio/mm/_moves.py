"""The moves one device started and the verdict owed to the next core call."""

from __future__ import annotations

import concurrent.futures
import threading
from typing import Any


class Moves:
    """The motion calls a device started in the driver's thread, each a future that ends
    with the driver's verdict on the moved axes; a failure is kept until the next core
    call takes it (:meth:`check`). Thread-safe: the core calls from any of its threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._running: list[concurrent.futures.Future[Any]] = []
        self._stopped: set[concurrent.futures.Future[Any]] = set()
        self._failure: BaseException | None = None
        self._ended = False

    def add(self, future: concurrent.futures.Future[Any]) -> None:
        """Follow ``future`` (a move just started)."""
        with self._lock:
            self._running.append(future)

    def _collect(self) -> None:
        """Forget the moves that ended; keep the first failure of one not stopped on
        purpose (held by the caller's lock)."""
        ended = [future for future in self._running if future.done()]
        self._ended = self._ended or bool(ended)
        for future in ended:
            self._running.remove(future)
            stopped = future in self._stopped
            self._stopped.discard(future)
            if future.cancelled() or stopped:
                continue
            error = future.exception()
            if error is not None and self._failure is None:
                self._failure = error

    def check(self) -> None:
        """Raise the failure of a move that ended since the last check, once."""
        with self._lock:
            self._collect()
            failure, self._failure = self._failure, None
        if failure is not None:
            raise failure

    def busy(self) -> bool:
        """Whether a move started here has not had its verdict yet; raises a failed
        move's error (see :meth:`check`)."""
        self.check()
        with self._lock:
            return bool(self._running)

    def ended(self) -> bool:
        """Whether a move has ended since the last call (the position changed): once."""
        with self._lock:
            self._collect()
            ended, self._ended = self._ended, False
        return ended

    def stopping(self) -> list[concurrent.futures.Future[Any]]:
        """Mark the running moves as stopped on purpose (their error is not a failure to
        report) and return them."""
        with self._lock:
            running = list(self._running)
            self._stopped.update(running)
            return running
