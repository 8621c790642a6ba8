"""Stray bytes without a CR in front of a reply, on a wire paced at 57600 Bd: the line
started before its read was written, so it is not the read's reply. The read fails with a
typed error (the stream resyncs) instead of returning a glued value (``1`` + ``0.0000``
read as ``10.0000``)."""

from __future__ import annotations

import random
from collections.abc import Callable

import pytest
from helpers import Emulated, EmulatorFactory, make_model, serve_pty, wait_until

import tango_aio
from tango_aio.controller._controller import Controller
from tango_aio.errors import ProtocolError
from tango_aio.sim.wire import Wire

pytestmark = pytest.mark.virtual_clock

PACED = "sim://?baud=57600"


def _held(tango: Controller) -> int:
    """Bytes of an unfinished line the driver holds."""
    return tango.protocol.core._assembler.buffered


async def _glued_read(tango: Controller, emit: Callable[[bytes], None],
                      noise: bytes) -> str:
    """Let ``noise`` (no CR) reach the driver, then read ``?pos x``. A read of another
    shape goes first, so that the driver writes nothing between (no separator): the
    first line back is the read's own reply, glued behind the noise."""
    await tango.query("?statusaxis")
    before = _held(tango)
    emit(noise)
    await wait_until(lambda: _held(tango) >= before + len(noise))
    return await tango.query("?pos x")


@pytest.mark.parametrize("mode", [1, 2, 4])
async def test_noise_glued_in_front_of_a_reply_fails_the_read(
        emulator: EmulatorFactory, mode: int) -> None:
    emu = await emulator(PACED, autostatus=mode)
    tango = emu.tango
    truth = await tango.query("?pos x")
    with pytest.raises(ProtocolError, match="started before the request could have been"):
        await _glued_read(tango, emu.wire.emit, b"1")
    assert await tango.query("?pos x") == truth  # the stream is in step again


async def test_over_a_pty_at_57600_too() -> None:
    """Over a pty the driver takes the port's rate for no proof of the wire's (USB units
    run faster, L10): what still tells is that the line started before the write."""
    async with await serve_pty(make_model) as server, \
            tango_aio.connect(server.path, baudrate=57600) as tango:
        wire: Wire = server.wire
        truth = await tango.query("?pos x")
        with pytest.raises(ProtocolError, match="started before"):
            await _glued_read(tango, wire.emit, b"1")
        assert await tango.query("?pos x") == truth


async def _fuzz(emu: Emulated, reads: int, seed: int) -> None:
    rng = random.Random(seed)
    tango = emu.tango
    truth = await tango.query("?pos x")
    failed = 0
    for _ in range(reads):
        if rng.random() < 0.5:
            size = rng.randint(1, 12)
            noise = bytes(rng.choice(b"0123456789.- +eE@xyz#") for _ in range(size))
            if not noise.strip():
                noise = b"7"
            try:
                value = await _glued_read(tango, emu.wire.emit, noise)
            except tango_aio.TangoError:
                failed += 1
                continue
            pytest.fail(f"{noise!r} in front of the reply gave {value!r}")
        assert await tango.query("?pos x") == truth
    assert failed > 0


@pytest.mark.parametrize("reads", [
    pytest.param(20, id="quick"),
    pytest.param(600, id="full", marks=pytest.mark.slow),
])
async def test_random_noise_before_reads_never_gives_a_value(
        emulator: EmulatorFactory, reads: int) -> None:
    emu = await emulator(PACED)
    await _fuzz(emu, reads, seed=reads)
