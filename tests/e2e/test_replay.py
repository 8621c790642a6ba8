"""A recorded wire trace replays as a test (issue #32): :func:`tango_aio.testing.replay`
plays the controller's side and checks that the driver writes the same lines; a trace
edited to differ fails naming the first differing line. The trace format is the driver's
wire log (:mod:`tango_aio.fieldkit._trace`)."""

from __future__ import annotations

import asyncio
import logging
import os
import sys
from pathlib import Path

import pytest

import tango_aio
from tango_aio.errors import TangoError
from tango_aio.fieldkit._trace import format_record, parse_trace, read_trace, record_trace
from tango_aio.testing import ReplayMismatch, replay

pytestmark = [pytest.mark.timeout(60), pytest.mark.virtual_clock]

ROOT = Path(__file__).resolve().parents[2]


async def session(url: str) -> None:
    """A short session: set-up, a set, moves, a read, a refused move."""
    async with tango_aio.connect(url, reply_timeout=2.0) as tango:
        await tango.set("vel", x=5)
        await tango.move_to(x=1.0, y=0.5)
        assert (await tango.position())["x"] == 1.0
        with pytest.raises(TangoError):
            await tango.move_to(x=99999)
        await tango.move_by(x=-1.0)


async def recorded(tmp_path: Path) -> Path:
    path = tmp_path / "session.trace"
    with record_trace(path):
        await session("sim://?baud=0")
    return path


async def test_a_recorded_session_replays(tmp_path: Path) -> None:
    path = await recorded(tmp_path)
    records = read_trace(path)
    assert {r.direction for r in records} == {"->", "<-"}
    assert path.read_text(encoding="utf-8").startswith("# tango_aio wire trace")
    async with replay(path) as player:
        await session(player.url)
    assert player.matched == sum(r.direction == "->" for r in records)


async def test_an_edited_trace_fails_naming_the_first_differing_line(tmp_path: Path) -> None:
    path = await recorded(tmp_path)
    lines = path.read_text(encoding="utf-8").splitlines()
    (index,) = [i for i, line in enumerate(lines) if line.endswith("-> b'!vel 5'")]
    lines[index] = lines[index].replace("b'!vel 5'", "b'!vel 6'")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ReplayMismatch, match=rf"trace line {index + 1}: the trace has "
                                             r"b'!vel 6', the client wrote b'!vel 5'"):
        async with replay(path) as player:
            await session(player.url)


async def test_a_client_that_stops_short_fails(tmp_path: Path) -> None:
    path = await recorded(tmp_path)
    with pytest.raises(ReplayMismatch, match="the client stopped writing"):
        async with replay(path) as player, tango_aio.connect(player.url, reply_timeout=2.0):
            pass


async def test_a_cut_received_line_cannot_be_played() -> None:
    text = "1.0 -> b'?pos'\n1.1 <- b'xxxx'... (300 bytes)\n"
    with pytest.raises(ValueError, match="trace line 2"):
        async with replay(text):
            pass


def test_the_trace_format_is_the_wire_log(caplog: pytest.LogCaptureFixture) -> None:
    line = b"\x03?help 72"
    assert format_record(12.5, "->", line) == "12.500000 -> b'\\x03?help 72'"
    long = b"x" * 300
    text = "\n".join([
        "# a comment",
        "DEBUG tango_aio.wire: " + format_record(1.0, "->", line),
        format_record(2.0, "<-", b"\nERROR 72,text"),
        format_record(3.0, "->", long),
        "an unrelated log line",
    ])
    records = parse_trace(text)
    assert [(r.time, r.direction, r.data, r.lineno) for r in records[:2]] == [
        (1.0, "->", line, 2), (2.0, "<-", b"\nERROR 72,text", 3)]
    assert records[2].length == 300 and records[2].data == b"x" * 256
    assert not records[2].complete
    # The driver's own logger writes the same records.
    with caplog.at_level(logging.DEBUG, logger="tango_aio.wire"):
        from tango_aio.link._router import wire_log

        wire_log.debug("%.6f -> %s", 5.0, repr(b"?pos"))
    assert parse_trace(caplog.text)[-1].data == b"?pos"


async def _cli(*args: str) -> tuple[int, str]:
    """``tango-aio -v ARGS`` in a subprocess: (exit code, its log on stderr)."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    process = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "tango_aio", "-v", *args, env=env,
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    _, err = await asyncio.wait_for(process.communicate(), 60)
    assert process.returncode is not None
    return process.returncode, err.decode("utf-8", "replace")


@pytest.mark.slow
async def test_the_demo_replays() -> None:
    """``tango-aio -v demo`` recorded on the emulator replays, three times over."""
    code, log = await _cli("demo", "--url", "sim://?baud=0&speed=20", "--rows", "2",
                           "--points", "3")
    assert code == 0, log
    for _ in range(3):
        async with replay(log) as player:
            code, again = await _cli("demo", "--url", player.url, "--rows", "2",
                                     "--points", "3", "--yes")
        assert code == 0, again
        assert player.matched > 50


@pytest.mark.slow
async def test_a_cli_session_logged_with_v_replays(tmp_path: Path) -> None:
    """``tango-aio -v COMMAND 2> FILE``: the log is a trace (its records among the log's
    other text), and the same command replays against it."""
    code, log = await _cli("info", "sim://?baud=0")
    assert code == 0, log
    records = parse_trace(log)
    assert len(records) > 10 and "tango_aio.wire" in log.splitlines()[0]
    async with replay(log) as player:
        code, again = await _cli("info", player.url)
    assert code == 0, again
    assert player.matched == sum(r.direction == "->" for r in records)
