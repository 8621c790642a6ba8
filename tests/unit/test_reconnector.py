"""The Reconnector on its own: a fake port and opener, no link, no emulator."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass, field
from typing import Any

import pytest

from tango_aio.errors import ConnectionLostError
from tango_aio.link._protocol import TangoProtocol
from tango_aio.link._reconnect import (
    Closer,
    IdentityMismatchError,
    Reconnect,
    Reconnector,
    ReconnectPolicy,
    Signature,
)

pytestmark = pytest.mark.timeout(10)

FAST = ReconnectPolicy(initial=0.001, maximum=0.002, attempts=4)
KNOWN: Signature = ("TANGO Desktop", "1.71", 3)


@dataclass
class Staged:
    """A throw-away controller: set up fails or succeeds as told."""

    signature: Signature | None
    fail_setup: BaseException | None = None
    closed: bool = False
    modes: list[int | None] = field(default_factory=list)

    async def setup(self, *, autostatus: int | None = 1, identify: bool = True) -> None:
        self.modes.append(autostatus)
        if self.fail_setup is not None:
            raise self.fail_setup

    async def aclose(self) -> None:
        self.closed = True


class FakeProtocol:
    def check(self) -> None:
        """The new link is up."""


class Port:
    """Records what the Reconnector asked of its controller."""

    def __init__(self, staged: list[Staged]) -> None:
        self.staged = staged
        self.used: list[Staged] = []
        self.calls: list[str] = []
        self.done = asyncio.Event()
        self.lost: ConnectionLostError | None = None
        self.attempt = 0

    @property
    def url(self) -> str:
        return "fake://"

    def signature(self, controller: Staged | None = None) -> Signature | None:
        return KNOWN if controller is None else controller.signature

    async def release_link(self) -> None:
        self.calls.append("release")

    def stage(self, protocol: TangoProtocol, closer: Closer | None) -> Staged:
        staged = self.staged.pop(0)
        self.used.append(staged)
        return staged

    def adopt(self, staged: Staged, closer: Closer | None) -> None:
        self.calls.append("adopt")

    def reconnected(self, attempt: int) -> None:
        self.attempt = attempt
        self.done.set()

    def give_up(self, lost: ConnectionLostError) -> None:
        self.lost = lost
        self.done.set()


def reconnector(port: Port, failures: list[BaseException] | None = None,
                policy: ReconnectPolicy = FAST) -> Reconnector[Any]:
    pending = list(failures or [])

    async def opener() -> tuple[TangoProtocol, Closer | None]:
        if pending:
            raise pending.pop(0)
        return FakeProtocol(), None  # type: ignore[return-value]

    return Reconnector(Reconnect(policy, opener), port)


async def test_not_armed_does_not_start() -> None:
    port = Port([])
    r = reconnector(port)
    assert r.start(1) is False
    assert not r.running and r.attempt == 0


async def test_retries_until_a_link_is_up_and_restores_the_mode() -> None:
    staged = Staged(KNOWN)
    port = Port([staged])
    r = reconnector(port, [ConnectionLostError("refused"), OSError("no route")])
    r.arm()
    assert r.start(2) is True
    assert r.start(2) is False  # one outage, one task
    await port.done.wait()
    assert port.lost is None and port.attempt == 3 == r.attempt
    assert staged.modes == [2] and not staged.closed
    assert port.calls == ["release", "release", "release", "adopt"]
    await r.stop()


async def test_another_controller_stops_at_once() -> None:
    other = Staged(("TANGO Desktop", "1.50", 3))
    port = Port([other, Staged(KNOWN)])
    r = reconnector(port)
    r.arm()
    r.start(1)
    await port.done.wait()
    assert isinstance(port.lost, ConnectionLostError)
    assert isinstance(port.lost.__cause__, IdentityMismatchError)
    assert other.closed and r.attempt == 1 and "adopt" not in port.calls


async def test_gives_up_after_the_attempts() -> None:
    port = Port([])
    r = reconnector(port, [OSError(f"down {n}") for n in range(10)])
    r.arm()
    r.start(1)
    await port.done.wait()
    assert port.lost is not None and r.attempt == FAST.attempts
    assert isinstance(port.lost.__cause__, OSError)


async def test_a_failed_setup_closes_the_staged_link_and_tries_again() -> None:
    bad = Staged(KNOWN, fail_setup=ConnectionLostError("dropped during setup"))
    good = Staged(None)  # not identified: no identity to compare
    port = Port([bad, good])
    r = reconnector(port)
    r.arm()
    r.start(1)
    await port.done.wait()
    assert bad.closed and not good.closed and port.attempt == 2


async def test_stop_while_setting_up_closes_the_staged_link() -> None:
    entered = asyncio.Event()

    class Hanging(Staged):
        async def setup(self, *, autostatus: int | None = 1, identify: bool = True) -> None:
            entered.set()
            await asyncio.Event().wait()

    hanging = Hanging(KNOWN)
    port = Port([hanging])
    r = reconnector(port)
    r.arm()
    r.start(1)
    await entered.wait()
    await r.stop()
    assert hanging.closed and not r.running and not port.done.is_set()
    assert r.start(1) is False  # stopped means disarmed
