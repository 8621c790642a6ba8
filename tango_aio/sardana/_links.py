"""One link per controller URL in a pool's process: the motor and the trigger-gate
controller of one TANGO share it (a serial port opens once)."""

from __future__ import annotations

import threading

import tango_aio.sync

__all__ = ["acquire", "release"]

_lock = threading.Lock()
#: URL → the link, how many controllers use it, and the units and reconnection it has.
_links: dict[str, tuple[tango_aio.sync.Controller, int, tuple[str, bool]]] = {}


def acquire(url: str, units: str, reconnect: bool) -> tango_aio.sync.Controller:
    """The open link to ``url`` (opened now if none is); ValueError if it is open with
    other units or reconnection."""
    with _lock:
        if url in _links:
            link, users, how = _links[url]
            if how != (units, reconnect):
                raise ValueError(f"{url} is open with Units {how[0]!r} and Reconnect "
                                 f"{how[1]!r}: give every controller of it the same")
            _links[url] = (link, users + 1, how)
            return link
        link = tango_aio.sync.connect(url, units=units, reconnect=reconnect)
        _links[url] = (link, 1, (units, reconnect))
        return link


def release(link: tango_aio.sync.Controller) -> None:
    """One user fewer of ``link``: closed with its last."""
    with _lock:
        url = next((u for u, (held, _, _) in _links.items() if held is link), None)
        if url is None:
            close = True
        else:
            _, users, how = _links[url]
            close = users == 1
            if close:
                del _links[url]
            else:
                _links[url] = (link, users - 1, how)
    if close:
        link.close()
