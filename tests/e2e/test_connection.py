"""connect(): the port is released when aclose() returns (issue 14 item 10), the
``Connecting`` object is a coroutine (``asyncio.run(tango_aio.connect(url))``), the
public names (issue 15 item 4) and AxisStatus."""

from __future__ import annotations

import asyncio
import inspect
import os

import pytest
from helpers import INSTANT, make_model, serve_pty

import tango_aio
from tango_aio import AxisStatus


def _lockable(path: str) -> bool:
    """Whether another program could take the exclusive lock of ``path`` right now."""
    import fcntl  # POSIX only; the tests that call this need the pty emulator anyway

    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return False
    finally:
        os.close(fd)
    return True


async def test_aclose_returns_once_the_serial_port_is_released() -> None:
    async with await serve_pty(make_model) as server:
        for _ in range(5):
            tango = await tango_aio.connect(server.path, autostatus=None)
            assert not _lockable(server.path)  # opened exclusively
            await tango.get("pos")
            await tango.aclose()
            assert _lockable(server.path)  # released before aclose() returned
        async with tango_aio.connect(server.path) as tango:  # at once, no retry
            assert await tango.status() == {"x": "@", "y": "@", "z": "@"}


async def test_a_second_open_of_the_same_port_fails() -> None:
    async with await serve_pty(make_model) as server, tango_aio.connect(server.path):
        with pytest.raises(tango_aio.PortBusyError, match="busy"):
            await tango_aio.connect(server.path)


def test_connecting_is_a_coroutine_for_asyncio_run_and_tasks() -> None:
    async def main() -> dict[str, float]:
        tango = await tango_aio.connect(INSTANT)
        try:
            return await tango.position()
        finally:
            await tango.aclose()

    assert asyncio.run(main()) == {"x": 0.0, "y": 0.0, "z": 0.0}
    assert asyncio.run(_connect_and_close()) == "TANGO-DT"
    connecting = tango_aio.connect(INSTANT)
    assert asyncio.iscoroutine(connecting)
    connecting.close()  # never started: nothing opened, no "never awaited" warning


async def _connect_and_close() -> str:
    tango = await asyncio.create_task(tango_aio.connect(INSTANT))  # a coroutine for tasks
    try:
        return tango.identity.model
    finally:
        await tango.aclose()


def test_asyncio_run_accepts_the_connecting_object() -> None:
    tango = asyncio.run(tango_aio.connect(INSTANT))
    assert tango.identity.axes == 3
    # Its loop is gone now; the emulator went with it. Nothing leaks a warning.


def test_connect_options_are_keywords() -> None:
    parameters = inspect.signature(tango_aio.connect).parameters
    assert "options" not in parameters
    assert all(p.kind is p.KEYWORD_ONLY for name, p in parameters.items() if name != "url")
    with pytest.raises(TypeError):
        tango_aio.connect(INSTANT, reconect=True)  # type: ignore[call-arg]


def test_every_error_event_group_and_upload_class_is_exported() -> None:
    import tango_aio.errors
    import tango_aio.events
    import tango_aio.families._bulk
    import tango_aio.group._discovery
    import tango_aio.group._group
    import tango_aio.link._reconnect

    for module in (tango_aio.errors, tango_aio.events, tango_aio.group._group,
                   tango_aio.families._bulk, tango_aio.link._reconnect,
                   tango_aio.group._discovery):
        for name, value in vars(module).items():
            if (inspect.isclass(value) and value.__module__ == module.__name__
                    and not name.startswith("_")
                    and (issubclass(value, BaseException) or module is not tango_aio.families._bulk)
                    and name not in ("EventHub", "Reconnect", "Reconnector", "ReconnectPort",
                                     "Stageable")):
                assert name in tango_aio.__all__, f"{module.__name__}.{name}"
                assert getattr(tango_aio, name) is value
    for name in tango_aio.__all__:
        assert getattr(tango_aio, name).__doc__, name


async def test_identity_is_not_optional() -> None:
    async with tango_aio.connect(INSTANT) as tango:
        assert tango.identity.model == "TANGO-DT"  # no assert-is-not-None needed
    async with tango_aio.connect(INSTANT, identify=False) as tango:
        with pytest.raises(RuntimeError, match="not identified"):
            tango.identity  # noqa: B018


async def test_axis_status() -> None:
    assert AxisStatus("M") is AxisStatus.MOVING
    assert str(AxisStatus.MOVING) == "M"
    assert AxisStatus.of("U") is AxisStatus.MANUAL_ADJUSTMENT
    assert {s for s in AxisStatus if s.is_failure} == {AxisStatus.ERROR,
                                                       AxisStatus.LIMIT_SWITCH,
                                                       AxisStatus.TIMEOUT}
    with pytest.raises(ValueError, match="unknown axis status"):
        AxisStatus.of("?")
    assert all(status.meaning for status in AxisStatus)
    async with tango_aio.connect(INSTANT) as tango:
        statuses = await tango.axis_status()
        assert statuses == {"x": AxisStatus.READY, "y": AxisStatus.READY,
                            "z": AxisStatus.READY}
        assert f"{statuses['x']}" == "@"


async def test_trigger_helpers() -> None:
    async with tango_aio.connect(INSTANT) as tango:
        assert await tango.triggers.count() == 0
        assert await tango.triggers.enabled() is False
        await tango.triggers.set_enabled(True)
        assert await tango.triggers.enabled() is True
        await tango.triggers.set_enabled(False)
        await tango.triggers.set_count(5)
        assert await tango.triggers.count() == 5
        with pytest.raises(TypeError):
            await tango.triggers.set_enabled(1)  # type: ignore[arg-type]


async def test_the_loop_under_test() -> None:
    """TANGO_AIO_TEST_LOOP=uvloop really runs the tests on uvloop."""
    loop = asyncio.get_running_loop()
    expected = os.environ.get("TANGO_AIO_TEST_LOOP", "asyncio")
    assert ("uvloop" in type(loop).__module__) == (expected == "uvloop")
