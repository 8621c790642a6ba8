"""The emulator for your own tests: a pytest plugin and a fault-injection handle.

Installing tango-aio registers this module as a pytest plugin (entry point ``pytest11``),
so these fixtures are available in any project's tests without a ``conftest.py``:

``tango_emulator``
    An :class:`Emulated` controller (async; needs pytest-asyncio): ``.tango`` is the
    connected :class:`tango_aio.Controller`, ``.faults`` its :class:`Faults`. Closed at
    teardown.
``tango_emulator_factory``
    An async factory, ``await tango_emulator_factory(profile=..., axes=..., speed=...)``,
    for several emulators or options per call; all are closed at teardown.
``tango_emulator_sync``
    The same as ``tango_emulator`` with a blocking :class:`tango_aio.sync.Controller`
    (no asyncio plugin needed).

Options, by priority: the test's marker ``@pytest.mark.tango_emulator(profile="manual",
axes=2, speed="real")``, then the command line / ini (``--tango-profile``,
``--tango-axes``, ``--tango-speed``), then the defaults: firmware profile ``manual``
(:mod:`tango_aio.sim.profiles`), 3 axes, speed ``fast``.

Speeds: ``fast`` - no line pacing (``baud=0``) and quick motion (100 mm/s, 20 m/s²) so
that moves take milliseconds; ``instant-line`` - no line pacing, the controller's own
motion settings; ``real`` - 57600 Bd pacing and the controller's own settings.

:func:`faults` gives the fault-injection handle of any ``sim://`` controller::

    faults = tango_aio.testing.faults(tango)
    faults.drop()           # the next reply is lost
    faults.garble()         # the next reply has one bit flipped
    faults.garble(reply_to="?err")    # ... the reply to the next ?err line
    faults.glue(b"7", reply_to="?err")  # stray bytes glued onto that reply
    faults.noise(b"x?\\r")   # bytes arrive that no request asked for
    faults.stall(0.5)       # the controller stops reading for 0.5 s
    faults.disconnect()     # the link is cut
    faults.axes()["x"]      # (position, velocity): where the emulated X axis really is

:func:`replay` plays a recorded wire trace back (a session on a real unit, recorded with
:func:`tango_aio.fieldkit.record_trace` or ``tango-aio probe --trace``) and checks that the
driver writes the same lines: see :mod:`tango_aio.fieldkit`.
"""

from __future__ import annotations

import math
import random
import urllib.parse
from collections.abc import AsyncIterator, Awaitable, Callable, Iterator
from dataclasses import dataclass
from typing import Any, Literal

import pytest

from .controller import Controller, connect
from .fieldkit import Replay, ReplayMismatch, replay
from .sim.model import ControllerModel
from .sim.wire import Garbler, Wire, flip_one_bit
from .sync import Controller as SyncController
from .sync import connect as sync_connect

__all__ = [
    "SPEEDS",
    "Emulated",
    "EmulatedSync",
    "Faults",
    "Replay",
    "ReplayMismatch",
    "emulator_url",
    "faults",
    "open_emulated",
    "pytest_addoption",
    "pytest_configure",
    "replay",
    "tango_emulator",
    "tango_emulator_factory",
    "tango_emulator_sync",
]

Speed = Literal["fast", "instant-line", "real"]

#: The speed options of the fixtures (see the module documentation).
SPEEDS: tuple[str, ...] = ("fast", "instant-line", "real")

#: Settings that make moves quick on every axis (``speed="fast"``).
_FAST_MOTION = {"secvel": 100, "vel": 100, "accel": 20, "stopaccel": 20}


def emulator_url(*, profile: str = "manual", axes: int = 3, speed: str = "fast",
                 **switches: str) -> str:
    """The ``sim://`` URL of an emulator with these options (``switches``: single
    firmware switches of :mod:`tango_aio.sim.profiles`, e.g. ``echo="after"``).

    Parameters
    ----------
    profile
        The firmware profile of :mod:`tango_aio.sim.profiles`.
    axes
        The number of axes (1-4).
    speed
        One of :data:`SPEEDS` (see the module text).
    **switches
        Single firmware switches, by name.

    Returns
    -------
    str
        The URL, for :func:`tango_aio.connect`.

    Raises
    ------
    ValueError
        An unknown ``speed``, or ``axes`` outside 1-4.
    """
    if speed not in SPEEDS:
        raise ValueError(f"speed must be one of {SPEEDS}, got {speed!r}")
    if isinstance(axes, bool) or not isinstance(axes, int) or not 1 <= axes <= 4:
        raise ValueError(f"axes must be 1..4, got {axes!r}")
    query = {"profile": profile, "axes": str(axes), "baud": "57600" if speed == "real" else "0",
             **switches}
    return "sim://?" + urllib.parse.urlencode(query)


class Faults:
    """Fault injection on an emulated (``sim://``) controller's link.

    Each method acts on the link the controller uses at the moment of the call (a
    reconnect opens a new one). Call it from the event loop the controller runs on (for a
    :class:`tango_aio.sync.Controller` use :attr:`EmulatedSync.faults`, which does that).

    Parameters
    ----------
    controller
        The emulated controller.
    run
        Runs a call on the controller's event loop; ``None`` to call directly.
    """

    def __init__(self, controller: Controller,
                 run: Callable[[Callable[[], None]], None] | None = None) -> None:
        self._controller = controller
        self._run = run

    @property
    def wire(self) -> Wire:
        """The emulated link (counters such as ``lines_processed``, ``dropped_replies``)."""
        transport = self._controller.protocol.transport
        wire = transport.get_extra_info("wire") if transport is not None else None
        if not isinstance(wire, Wire):
            raise TypeError(f"{self._controller.url!r} is not an emulated (sim://) link")
        return wire

    @property
    def model(self) -> ControllerModel:
        """The emulated controller's interpreter (its state, for assertions)."""
        handler = self.wire.handler
        assert isinstance(handler, ControllerModel)
        return handler

    def axes(self) -> dict[str, tuple[float, float]]:
        """Where the emulated axes really are now: axis letter → ``(position in its dim
        unit, velocity in rev/s)``, read from the motion model without advancing it. An
        axis that a move claimed to reach stands still there: velocity ``0.0`` and the
        position within the display's precision of the target.

        Returns
        -------
        dict[str, tuple[float, float]]
            The position and velocity of each axis, by axis letter.
        """
        wire = self.wire
        now = wire.clock() if wire.clock is not None else wire.now
        model = self.model
        return {axis: model.motion.observe(index, now)
                for index, axis in enumerate("xyza"[: model.axes])}

    def pulse_snapshot_input(self, index: int = 3) -> None:
        """One pulse on the emulated AUX input ``index`` (3, the SnapShot pin, by
        default), now: to its active level and back, as a camera's trigger output drives
        it (a snapshot event if the input has the snapshot function: manual chapter 23).

        Parameters
        ----------
        index
            The AUX input, from 0.
        """
        def action(wire: Wire) -> None:
            model = wire.handler
            assert isinstance(model, ControllerModel)
            model.pulse_snapshot_input(index, wire.clock() if wire.clock is not None
                                       else wire.now)
            wire.handler_changed()
        self._do(action)

    def _do(self, action: Callable[[Wire], None]) -> None:
        wire = self.wire
        if self._run is None:
            action(wire)
        else:
            self._run(lambda: action(wire))

    def drop(self, replies: int = 1) -> None:
        """Lose the next ``replies`` replies of the controller.

        Parameters
        ----------
        replies
            How many replies to lose.
        """
        self._do(lambda wire: setattr(wire.faults, "drop_replies",
                                      wire.faults.drop_replies + _count(replies)))

    def garble(self, replies: int = 1, *, reply_to: str | None = None) -> None:
        """Flip one bit in each of the next ``replies`` replies; with ``reply_to``, in
        the first reply to the next line the controller receives that starts with it
        instead (e.g. ``"?err"``: the verdict on the line before it), once.

        Parameters
        ----------
        replies
            How many replies to garble (without ``reply_to``).
        reply_to
            The start of the line whose reply is garbled (at least one character).
        """
        count = _count(replies)
        if reply_to is None:
            self._do(lambda wire: setattr(wire.faults, "garble_replies",
                                          wire.faults.garble_replies + count))
        else:
            self._garble_reply_to(reply_to, flip_one_bit)

    def glue(self, data: bytes, *, reply_to: str, before: bool = False) -> None:
        """Glue stray bytes onto the first reply to the next line the controller receives
        that starts with ``reply_to``, in the same line: behind its text (before its CR),
        or in front of it with ``before``. Once.

        Parameters
        ----------
        data
            The stray bytes (at least one).
        reply_to
            The start of the line whose reply gets them (at least one character).
        before
            Put them in front of the reply instead of behind its text.

        Raises
        ------
        ValueError
            ``data`` is empty.
        """
        if not data:
            raise ValueError("glue needs at least one byte")
        stray = bytes(data)

        def glued(reply: bytes, rng: random.Random) -> bytes:
            text, end = (reply[:-1], reply[-1:]) if reply.endswith(b"\r") else (reply, b"")
            return stray + reply if before else text + stray + end
        self._garble_reply_to(reply_to, glued)

    def _garble_reply_to(self, reply_to: str, garbler: Garbler) -> None:
        if not reply_to:
            raise ValueError("reply_to needs at least one character")
        target = (reply_to.encode("ascii"), garbler)
        self._do(lambda wire: setattr(wire.faults, "garble_reply_to", target))

    def delay(self, seconds: float, replies: int = 1) -> None:
        """Hold the next ``replies`` replies back by ``seconds`` (later output waits).

        Parameters
        ----------
        seconds
            The delay.
        replies
            How many replies to hold back.
        """
        _seconds(seconds)

        def action(wire: Wire) -> None:
            wire.faults.reply_delay = seconds
            wire.faults.delay_replies += _count(replies)
        self._do(action)

    def lose_line(self, prefix: str) -> None:
        """Lose the next line the controller receives that starts with ``prefix`` (e.g.
        ``"!mor"``), as if it never arrived: it is not executed and gets no answer; the
        lines behind it are executed as usual. Once.

        Parameters
        ----------
        prefix
            The start of the line to lose (at least one character).

        Raises
        ------
        ValueError
            ``prefix`` is empty.
        """
        if not prefix:
            raise ValueError("lose_line needs a prefix of at least one character")
        data = prefix.encode("ascii")
        self._do(lambda wire: setattr(wire.faults, "lose_line", data))

    def noise(self, data: bytes = b"\x15noise\r") -> None:
        """Send ``data`` to the driver as if the controller had sent it unasked.

        Parameters
        ----------
        data
            The bytes to send (at least one).

        Raises
        ------
        ValueError
            ``data`` is empty.
        """
        if not data:
            raise ValueError("noise needs at least one byte")
        self._do(lambda wire: wire.emit(bytes(data)))

    def stall(self, seconds: float) -> None:
        """Stop the controller's interpreter for ``seconds`` (input still fills the
        buffer; moves go on).

        Parameters
        ----------
        seconds
            How long the interpreter stops.
        """
        _seconds(seconds)
        self._do(lambda wire: wire.stall(seconds))

    def power_cycle(self, off: float = 0.2) -> None:
        """Switch the controller off now and on again ``off`` seconds later, behind a
        link that stays up (:meth:`tango_aio.sim.wire.Wire.power_cycle`): what it held and
        what arrives meanwhile is lost, and it restarts as at power-on (autostatus 1,
        settings from its state file, position counters 0).

        Parameters
        ----------
        off
            Seconds the controller stays off (input arriving meanwhile is lost).
        """
        off = _seconds(off)
        self._do(lambda wire: wire.power_cycle(off))

    def disconnect(self, *, mid_reply: bool = False) -> None:
        """Cut the link now, or halfway through the next reply.

        Parameters
        ----------
        mid_reply
            Cut the link halfway through the next reply instead of now.
        """
        self._do(lambda wire: wire.disconnect(mid_reply=mid_reply))


def _seconds(seconds: float) -> float:
    """Refuse a time that is not a finite number of seconds >= 0 (nan, -1, inf, a bool)."""
    if isinstance(seconds, bool) or not isinstance(seconds, int | float) \
            or not math.isfinite(seconds) or seconds < 0:
        raise ValueError(f"seconds must be a finite number >= 0, got {seconds!r}")
    return float(seconds)


def _count(replies: int) -> int:
    if isinstance(replies, bool) or not isinstance(replies, int) or replies < 1:
        raise ValueError(f"replies must be a positive integer, got {replies!r}")
    return replies


def faults(controller: Controller) -> Faults:
    """The fault-injection handle of an emulated controller (``TypeError`` when it is not
    connected to ``sim://``).

    Parameters
    ----------
    controller
        A controller connected to ``sim://``.

    Returns
    -------
    Faults
        Its fault-injection handle.
    """
    handle = Faults(controller)
    handle.wire  # noqa: B018 - fails early for a real link
    return handle


@dataclass
class Emulated:
    """An async controller connected to a fresh in-process emulator."""

    tango: Controller
    faults: Faults
    url: str


@dataclass
class EmulatedSync:
    """A blocking controller connected to a fresh in-process emulator."""

    tango: SyncController
    faults: Faults
    url: str


async def open_emulated(*, profile: str = "manual", axes: int = 3, speed: str = "fast",
                        **connect_options: Any) -> Emulated:
    """Connect to a fresh emulator with these options (see :func:`emulator_url`);
    ``connect_options`` go to :func:`tango_aio.connect`. Close ``.tango`` when done.

    Parameters
    ----------
    profile
        The firmware profile (see :func:`emulator_url`).
    axes
        The number of axes (1-4).
    speed
        One of :data:`SPEEDS`.
    **connect_options
        Options of :func:`tango_aio.connect`.

    Returns
    -------
    Emulated
        The connected controller, its fault handle and its URL.
    """
    url = emulator_url(profile=profile, axes=axes, speed=speed)
    tango = await connect(url, **connect_options)
    try:
        if speed == "fast":
            await _make_fast(tango, axes)
    except BaseException:
        await tango.aclose()
        raise
    return Emulated(tango, Faults(tango), url)


async def _make_fast(tango: Controller, axes: int) -> None:
    present = "xyza"[:axes]
    for name, value in _FAST_MOTION.items():
        await tango.set(name, axis=None, check=True, **dict.fromkeys(present, value))


# --------------------------------------------------------------------------------------
# The pytest plugin


def pytest_addoption(parser: pytest.Parser) -> None:
    """Command-line and ini options of the fixtures.

    Parameters
    ----------
    parser
        pytest's option parser.
    """
    group = parser.getgroup("tango_aio", "TANGO emulator fixtures (tango_aio.testing)")
    for name, help_text, default in (
            ("profile", "firmware profile of the emulator (tango_aio.sim.profiles)", "manual"),
            ("axes", "number of emulated axes (1-4)", "3"),
            ("speed", f"one of {', '.join(SPEEDS)}", "fast")):
        group.addoption(f"--tango-{name}", dest=f"tango_{name}", default=None, help=help_text)
        parser.addini(f"tango_{name}", help_text, default=default)


def pytest_configure(config: pytest.Config) -> None:
    """Register the ``tango_emulator`` marker.

    Parameters
    ----------
    config
        pytest's configuration.
    """
    config.addinivalue_line(
        "markers", "tango_emulator(profile=..., axes=..., speed=...): options of the "
        "tango_emulator fixtures for this test")


def _options(request: pytest.FixtureRequest) -> dict[str, Any]:
    config = request.config
    options: dict[str, Any] = {}
    for name in ("profile", "axes", "speed"):
        value = config.getoption(f"tango_{name}") or config.getini(f"tango_{name}")
        options[name] = int(value) if name == "axes" else str(value)
    marker = request.node.get_closest_marker("tango_emulator")
    if marker is not None:
        options.update(marker.kwargs)
    return options


def _async_fixture(func: Callable[..., Any]) -> Any:
    try:
        import pytest_asyncio
    except ImportError:  # the sync fixture still works
        def needs_plugin(request: pytest.FixtureRequest) -> None:
            pytest.fail("the tango_emulator fixtures need pytest-asyncio "
                        "(pip install pytest-asyncio), or use tango_emulator_sync")
        needs_plugin.__name__ = func.__name__
        needs_plugin.__doc__ = func.__doc__
        return pytest.fixture(needs_plugin)
    return pytest_asyncio.fixture(func)


@_async_fixture
async def tango_emulator_factory(request: pytest.FixtureRequest
                                 ) -> AsyncIterator[Callable[..., Awaitable[Emulated]]]:
    """Factory of emulated controllers: ``await tango_emulator_factory(**options)``;
    every one is closed at teardown. Options default to the marker's, then the command
    line's (see :mod:`tango_aio.testing`).

    Parameters
    ----------
    request
        pytest's fixture request (for the marker and the options).

    Yields
    ------
    Callable[..., Awaitable[Emulated]]
        The factory: its keyword arguments are those of :func:`open_emulated`.
    """
    defaults = _options(request)
    opened: list[Emulated] = []

    async def open_one(**options: Any) -> Emulated:
        emulated = await open_emulated(**{**defaults, **options})
        opened.append(emulated)
        return emulated

    yield open_one
    for emulated in opened:
        await emulated.tango.aclose()


@_async_fixture
async def tango_emulator(request: pytest.FixtureRequest) -> AsyncIterator[Emulated]:
    """A controller connected to a fresh emulator (``.tango``, ``.faults``), closed at
    teardown. Options: see :mod:`tango_aio.testing`.

    Parameters
    ----------
    request
        pytest's fixture request (for the marker and the options).

    Yields
    ------
    Emulated
        The connected controller, its fault handle and its URL.
    """
    emulated = await open_emulated(**_options(request))
    try:
        yield emulated
    finally:
        await emulated.tango.aclose()


@pytest.fixture
def tango_emulator_sync(request: pytest.FixtureRequest) -> Iterator[EmulatedSync]:
    """Like ``tango_emulator``, with a blocking :class:`tango_aio.sync.Controller`.

    Parameters
    ----------
    request
        pytest's fixture request (for the marker and the options).

    Yields
    ------
    EmulatedSync
        The connected blocking controller, its fault handle and its URL.
    """
    options = _options(request)
    url = emulator_url(**options)
    tango = sync_connect(url)
    try:
        portal = tango.portal
        if options["speed"] == "fast":
            portal.call(_make_fast, tango.aio, options["axes"])

        async def call_soon(action: Callable[[], None]) -> None:
            action()

        handle = Faults(tango.aio, lambda action: portal.call(call_soon, action))
        yield EmulatedSync(tango, handle, url)
    finally:
        tango.close()
