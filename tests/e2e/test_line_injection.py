"""Security: no CR, LF or Ctrl+C reaches the wire through any entry point; the TCP
emulator binds to loopback; the state file is replaced atomically."""

from __future__ import annotations

import os
from collections.abc import Awaitable, Callable
from pathlib import Path

import pytest
from helpers import (
    EmulatorFactory,
    make_model,
)

from tango_aio.catalog._encode import build, build_axes
from tango_aio.catalog._instructions import Command, encode, parse
from tango_aio.cli._shell import Shell
from tango_aio.controller._controller import Controller
from tango_aio.errors import (
    ControllerError,
    InvalidCommandError,
)
from tango_aio.sim.serve import serve_tcp

pytestmark = [pytest.mark.timeout(30), pytest.mark.virtual_clock]


class _NoInput:
    async def read(self) -> str:
        raise EOFError


def _hand_built(tango: Controller, char: str) -> Awaitable[object]:
    command = parse("!vel x 5")
    forged = Command(command.instruction, command.form, "x", (5,), (f"5{char}!moa 9",))

    async def submit() -> object:
        return tango.protocol.submit(forged)

    return submit()


#: Every public entry point that takes a string, with ``char`` smuggled into it.
ENTRY_POINTS: dict[str, Callable[[Controller, str], Awaitable[object]]] = {
    "query": lambda t, c: t.query(f"?pos{c}!moa 9 9"),
    "query-trailing": lambda t, c: t.query(f"?pos{c}"),
    "command": lambda t, c: t.command(f"!vel 5{c}!moa 9"),
    "command-unchecked": lambda t, c: t.command(f"!vel 5{c}", check=False),
    "get-name": lambda t, c: t.get(f"vel{c}"),
    "get-arg": lambda t, c: t.get("trigp", f"1{c}"),
    "get-axis": lambda t, c: t.get("vel", axis=f"x{c}"),
    "set-arg": lambda t, c: t.set("vel", f"5{c}!moa 9", axis="x"),
    "set-axis": lambda t, c: t.set("vel", 5, axis=f"y{c}"),
    "set-keyword": lambda t, c: t.set("vel", x=f"5{c}!moa 9"),
    "move_to": lambda t, c: t.move_to(x=f"1{c}!moa 9"),  # type: ignore[arg-type]
    "move_by": lambda t, c: t.move_by(y=f"1{c}"),  # type: ignore[arg-type]
    "go": lambda t, c: t.go(x=f"1{c}"),  # type: ignore[arg-type]
    "speed": lambda t, c: t.speed(x=f"1{c}"),  # type: ignore[arg-type]
    "calibrate": lambda t, c: t.calibrate(f"x{c}"),
    "measure_range": lambda t, c: t.measure_range(f"y{c}"),
    "move_to_center": lambda t, c: t.move_to_center(f"z{c}"),
    "triggers.set_range": lambda t, c: t.triggers.set_range(0, 1, 2, axis=f"x{c}"),
    "triggers.upload_positions":
        lambda t, c: t.triggers.upload_positions([1.0], axis=f"x{c}"),
    "shell": lambda t, c: Shell(t, _NoInput()).execute(f"?pos{c}!moa 9 9"),
    "protocol-submit": _hand_built,
}


@pytest.mark.parametrize("char", ["\r", "\n", "\x03"], ids=["CR", "LF", "ETX"])
@pytest.mark.parametrize("entry", sorted(ENTRY_POINTS))
async def test_control_characters_are_refused_before_writing(
        emulator: EmulatorFactory, monkeypatch: pytest.MonkeyPatch, entry: str,
        char: str) -> None:
    tango = (await emulator()).tango
    transport = tango.protocol.transport
    written: list[bytes] = []
    monkeypatch.setattr(transport, "write", written.append)
    with pytest.raises(InvalidCommandError):
        await ENTRY_POINTS[entry](tango, char)
    assert written == []


@pytest.mark.parametrize("char", ["\r", "\n", "\x03"], ids=["CR", "LF", "ETX"])
@pytest.mark.parametrize("call", [
    lambda c: encode(f"!vel 5{c}!moa 9"),
    lambda c: parse(f"?pos{c}"),
    lambda c: build("vel", f"5{c}", axis="x"),
    lambda c: build(f"vel{c}", 5),
    lambda c: build("vel", 5, axis=f"x{c}"),
    lambda c: build_axes("moa", {"x": f"1{c}!moa 9"}),
], ids=["encode", "parse", "build-value", "build-name", "build-axis", "build_axes"])
def test_the_catalog_refuses_control_characters(call: Callable[[str], object],
                                                char: str) -> None:
    with pytest.raises(InvalidCommandError):
        call(char)


async def test_tcp_emulator_binds_to_loopback_by_default() -> None:
    async with await serve_tcp(make_model) as server:
        assert server.host == "127.0.0.1"


async def test_the_state_file_is_replaced_atomically(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, emulator: EmulatorFactory) -> None:
    state = tmp_path / "tango.json"
    tango = (await emulator(f"sim://?baud=0&state={state}")).tango
    await tango.set("vel", 3, axis="x")
    await tango.command("save")
    old = state.read_bytes()

    def crash(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> None:
        raise OSError("power failure")

    monkeypatch.setattr(os, "replace", crash)
    await tango.set("vel", 7, axis="x")
    with pytest.raises(ControllerError) as info:
        await tango.command("save")
    assert info.value.number == 73
    assert state.read_bytes() == old  # the old file, whole
    assert os.listdir(tmp_path) == [state.name]  # no temp file left behind
