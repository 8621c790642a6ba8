"""``sim://`` URLs: an emulated controller inside the caller's event loop.

Options go in the query string, e.g. ``sim://?axes=2&baud=0&latency=0.002``:

=============  =========================================================  ===========
option         meaning                                                    default
=============  =========================================================  ===========
axes           number of axes (1-4)                                       3
baud           wire speed in Bd; ``0`` for instant mode (no pacing)       57600
latency        extra reply latency in seconds (USB adapters)              0
processing     interpreter time per line in seconds                       0
stall_every    stall the interpreter every N lines ...                    0 (never)
stall          ... for this many seconds                                  0
fragment       probability that a reply is split into pieces              0
seed           random seed for fragmentation and faults                   none
model          the ``?version`` controller type                           TANGO-DT
firmware       the firmware version                                       1.71
state          path of a JSON file where ``save`` persists settings        none
lacks          instructions it lacks (``ctrt,pause``): no reply, error 4  none
profile        firmware profile (:mod:`tango_aio.sim.profiles`)            manual
fingerprint    switches and lacks of a ``tango-aio probe`` fingerprint    none
<switch>       any switch of :data:`~tango_aio.sim.profiles.SWITCHES`      per profile
speed          the controller's time runs this many times as fast          1
=============  =========================================================  ===========

Example: ``sim://?profile=legacy&echo=after`` (the profile first, single switches on top).
``sim://?fingerprint=unit.json`` behaves like the unit ``tango-aio probe`` wrote
``unit.json`` for, as far as the switches go (:meth:`Firmware.from_fingerprint`), and
lacks the instructions it lacks (:func:`~tango_aio.sim.profiles.fingerprint_lacks`, on top
of any ``lacks`` option); single switches go on top of it too.
``speed`` (a finite number > 0) scales motion, pauses and the controller's timeouts; the
wire keeps its baud rate, latency and processing times (:mod:`tango_aio.sim.clock`).
"""

from __future__ import annotations

import asyncio
import urllib.parse
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import TypeVar

from .clock import check_speed
from .model import ControllerModel, SimConfig
from .profiles import SWITCHES, Firmware, fingerprint_lacks
from .serve import SimTransport, create_sim_connection
from .wire import Emit, WireConfig

__all__ = ["configs_from_url", "open_sim", "speed_from_url"]

_P = TypeVar("_P", bound=asyncio.Protocol)


def configs_from_url(url: str) -> tuple[SimConfig, WireConfig]:
    """Parse a ``sim://`` URL into the emulator's and the wire's configuration.

    Parameters
    ----------
    url
        The ``sim://`` URL.

    Returns
    -------
    tuple[SimConfig, WireConfig]
        The two configurations.

    Raises
    ------
    ValueError
        Not a ``sim://`` URL, or an unknown, invalid or conflicting option.
    """
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        raise ValueError(f"not a sim:// URL: {url!r}")
    query = dict(urllib.parse.parse_qsl(parts.query, strict_parsing=False))
    known = {"axes", "baud", "latency", "processing", "stall_every", "stall", "fragment",
             "seed", "model", "firmware", "state", "profile", "fingerprint", "speed", "lacks",
             *SWITCHES}
    unknown = set(query) - known
    if unknown:
        raise ValueError(f"unknown sim:// option(s) {sorted(unknown)}; known: {sorted(known)}")
    axes = int(query.get("axes", 3))
    if not 1 <= axes <= 4:
        raise ValueError(f"sim:// axes must be 1..4, got {axes}")
    switches = {name: value for name, value in query.items() if name in SWITCHES}
    lacks = frozenset(name.strip().lower() for name in query.get("lacks", "").split(",")
                      if name.strip())
    if "fingerprint" in query:
        if "profile" in query:
            raise ValueError("sim:// takes a profile or a fingerprint, not both")
        firmware = Firmware.from_fingerprint(query["fingerprint"]).with_(**switches)
        lacks |= fingerprint_lacks(query["fingerprint"])
    else:
        firmware = Firmware.from_options(query.get("profile", "manual"), **switches)
    sim = SimConfig(
        axes=axes,
        model=query.get("model", "TANGO-DT"),
        firmware=firmware,
        version=query.get("firmware", "1.71"),
        state_file=Path(query["state"]) if "state" in query else None,
        lacks=lacks,
    )
    baud = int(query.get("baud", 57600))
    wire = WireConfig(
        baud=baud or None,
        processing_time_per_line=float(query.get("processing", 0.0)),
        stall_every_lines=int(query.get("stall_every", 0)),
        stall_duration=float(query.get("stall", 0.0)),
        reply_latency=float(query.get("latency", 0.0)),
        fragment_probability=float(query.get("fragment", 0.0)),
        seed=int(query["seed"]) if "seed" in query else None,
    )
    return sim, wire


def speed_from_url(url: str) -> float:
    """The ``speed`` option of a ``sim://`` URL (1 if absent); ValueError if not > 0.

    Parameters
    ----------
    url
        The ``sim://`` URL.

    Returns
    -------
    float
        The speed factor.

    Raises
    ------
    ValueError
        The speed is not a finite number > 0.
    """
    query = dict(urllib.parse.parse_qsl(urllib.parse.urlsplit(url).query))
    text = query.get("speed", "1")
    try:
        return check_speed(float(text))
    except ValueError:
        raise ValueError(f"sim:// speed must be a finite number > 0, got {text!r}") from None


async def open_sim(
    url: str, protocol_factory: Callable[[], _P]
) -> tuple[_P, Callable[[], Awaitable[None]]]:
    """Connect ``protocol_factory()`` to a fresh in-process emulator described by ``url``.

    Returns the protocol and a coroutine function that shuts the emulator down.

    Parameters
    ----------
    url
        The ``sim://`` URL.
    protocol_factory
        Makes the protocol to connect.

    Returns
    -------
    tuple[_P, Callable[[], Awaitable[None]]]
        The connected protocol, and what shuts the emulator down.
    """
    sim, wire = configs_from_url(url)
    speed = speed_from_url(url)

    def make_handler(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, sim)

    transport, protocol = await create_sim_connection(protocol_factory, make_handler, wire,
                                                      speed=speed)

    async def close() -> None:
        transport.close()
        await _wait_closed(transport)

    return protocol, close


async def _wait_closed(transport: SimTransport) -> None:
    await transport.wait_closed()
