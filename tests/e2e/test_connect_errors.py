"""Connect errors in the user's terms, each a typed :class:`ConnectError` with the next
step, kept apart from :class:`ConnectionLostError` (issue 30 items 2 and 10)."""

from __future__ import annotations

import os
import socket

import pytest
import serial
from helpers import make_model, posix_only, serve_pty

import tango_aio
from tango_aio import (
    ConnectError,
    ConnectionLostError,
    ControllerTimeoutError,
    NoControllerError,
    PortBusyError,
    PortNotFoundError,
    PortPermissionError,
)
from tango_aio._platform import WINDOWS


def _one_errno(text: str) -> bool:
    return text.count("Errno") == 0


async def test_a_missing_port_is_port_not_found() -> None:
    with pytest.raises(PortNotFoundError) as info:
        await tango_aio.connect("/dev/ttyUSB-none-such")
    text = str(info.value)
    assert "no serial port /dev/ttyUSB-none-such" in text and "tango-aio ports" in text
    assert _one_errno(text), text
    assert not isinstance(info.value, ConnectionLostError)
    assert isinstance(info.value, ConnectError) and info.value.url == "/dev/ttyUSB-none-such"


async def test_a_port_held_by_another_program_is_busy() -> None:
    async with await serve_pty(make_model) as server, tango_aio.connect(server.path):
        with pytest.raises(PortBusyError, match="another program holds it") as info:
            await tango_aio.connect(server.path)
    assert _one_errno(str(info.value)) and "lock" not in str(info.value)


async def test_permission_denied_names_the_dialout_group(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # We run as root, which may open any port: the refusal is made at the open boundary,
    # as pyserial raises it for a port of mode 600 owned by someone else.
    def refuse(url: str, **_: object) -> None:
        raise serial.SerialException(
            13, f"could not open port {url}: [Errno 13] Permission denied: {url!r}")

    monkeypatch.setattr(serial, "serial_for_url", refuse)
    # The dialout group is Linux's answer for a serial adapter; Windows has none.
    advice = "close that program" if WINDOWS else "add yourself to the dialout group"
    with pytest.raises(PortPermissionError, match=advice) as info:
        await tango_aio.connect("/dev/ttyUSB0")
    assert _one_errno(str(info.value)), info.value


async def test_a_silent_port_is_no_controller_in_the_users_terms() -> None:
    posix_only("a pty pair nobody answers on (os.openpty)")
    master, slave = os.openpty()  # nobody answers on the other end
    try:
        path = os.ttyname(slave)
        with pytest.raises(NoControllerError) as info:
            await tango_aio.connect(path, reply_timeout=0.2)
    finally:
        os.close(master)
        os.close(slave)
    text = str(info.value)
    assert text == (f"no TANGO answered on {path} at 57600 Bd: is it switched on, is this "
                    f"its port? `tango-aio ports --probe` lists the ports that answer")
    assert isinstance(info.value, ControllerTimeoutError)  # what nothing answering is
    assert not isinstance(info.value, ConnectionLostError)


async def test_a_refused_tcp_connection_is_a_connect_error() -> None:
    with socket.socket() as probe:  # a free port that nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(ConnectError, match=r"cannot connect to socket://127\.0\.0\.1") as info:
        await tango_aio.connect(f"socket://127.0.0.1:{port}")
    assert not isinstance(info.value, ConnectionLostError)


@pytest.mark.parametrize(("url", "hint"), [
    ("tcp://127.0.0.1:4001", "socket://127.0.0.1:4001"),
    ("TCP://host:1", "socket://host:1"),
    ("telnet://host:23", "socket://host:23"),
    ("sim:/", "sim://"),
    ("sim:?axes=2", "sim://?axes=2"),
    ("socket:/host:1", "socket://host:1"),
])
def test_almost_urls_are_refused_with_the_right_spelling(url: str, hint: str) -> None:
    with pytest.raises(ValueError, match="write " + hint.replace("?", r"\?")):
        tango_aio.connect(url)  # before anything is opened
