"""A Tango Controls client in a process of its own, for ``test_tango_controls.py``: it
reads one JSON request a line on stdin and answers each with one JSON line on stdout.

``python tango_controls_client.py tango://127.0.0.1:PORT/marzhauser/stage/ [SUFFIX]`` (the
suffix of each device's address, ``#dbase=no`` unless given) then, e.g.,
``{"op": "subscribe", "device": "x", "attrs": ["State", "Position"]}``. Change events are
recorded as they arrive (``events`` hands them over), in arrival order.
"""

from __future__ import annotations

import json
import sys
import threading
import time
from typing import Any

import tango


def plain(value: Any) -> Any:
    """A value JSON can carry (a DevState as its name, arrays as lists)."""
    if isinstance(value, tango.DevState):
        return str(value)
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


class Client:
    """The proxies and the events they delivered."""

    def __init__(self, base: str, suffix: str = "#dbase=no") -> None:
        self.base, self.suffix = base, suffix
        self.proxies: dict[str, tango.DeviceProxy] = {}
        self.events: list[list[Any]] = []
        self.lock = threading.Lock()

    def proxy(self, device: str) -> tango.DeviceProxy:
        if device not in self.proxies:
            self.proxies[device] = tango.DeviceProxy(f"{self.base}{device}{self.suffix}")
        return self.proxies[device]

    def record(self, device: str, event: Any) -> None:
        name = str(event.attr_name).partition("#")[0].rsplit("/", 1)[-1].lower()
        if event.err:
            entry = [device, name, "error", str(event.errors[0].desc)]
        else:
            entry = [device, name, plain(event.attr_value.value)]
        with self.lock:
            self.events.append(entry)

    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        op = request["op"]
        proxy = self.proxy(request.get("device", "x"))
        if "timeout_ms" in request:
            proxy.set_timeout_millis(int(request["timeout_ms"]))
        if op == "subscribe":
            for attr in request["attrs"]:
                device = request.get("device", "x")
                proxy.subscribe_event(attr, tango.EventType.CHANGE_EVENT,
                                      lambda e, d=device: self.record(d, e))
            return {"ok": True}
        if op == "events":
            return {"events": self.take(request.get("device", "x"), request.get("until"))}
        if op == "write":
            proxy.write_attribute(request["attr"], request["value"])
            return {"ok": True}
        if op == "command":
            arg = request.get("arg")
            result = proxy.command_inout(request["name"]) if arg is None else \
                proxy.command_inout(request["name"], arg)
            return {"result": plain(result)}
        if op == "read":
            return {"values": {a: plain(proxy.read_attribute(a).value)
                               for a in request["attrs"]}}
        if op == "polled":
            return {"polled": bool(proxy.is_attribute_polled(request["attr"]))}
        if op == "until":
            return self.until(proxy, request["leave"], request.get("timeout", 60))
        if op == "moves":
            return {"rounds": [self.move(proxy, float(target)) for target in request["targets"]]}
        raise ValueError(f"unknown op {op!r}")

    def take(self, device: str, until: str | None) -> list[list[Any]]:
        """The events so far (once the latest State event of ``device`` is ``until``,
        if given: events come on their own path, after the reads that saw the state)."""
        deadline = time.monotonic() + 60
        while until is not None and time.monotonic() < deadline:
            with self.lock:
                seen = [e[2] for e in self.events if e[0] == device and e[1] == "state"]
            if seen and seen[-1] == until:
                break
            time.sleep(0.01)
        with self.lock:
            events, self.events = self.events, []
        return events

    def until(self, proxy: tango.DeviceProxy, leave: list[str], timeout: float
              ) -> dict[str, Any]:
        """Read State and Position together until State is none of ``leave``."""
        samples: list[list[Any]] = []
        deadline = time.monotonic() + timeout
        while True:
            state, position = (plain(a.value) for a in
                               proxy.read_attributes(["State", "Position"]))
            samples.append([state, position])
            if state not in leave or time.monotonic() > deadline:
                break
            time.sleep(0.005)
        return {"state": samples[-1][0], "position": samples[-1][1],
                "status": proxy.status(), "samples": samples}

    def move(self, proxy: tango.DeviceProxy, target: float) -> dict[str, Any]:
        proxy.write_attribute("Position", target)
        return self.until(proxy, ["MOVING"], 60)


def main() -> None:
    client = Client(*sys.argv[1:3])
    for line in sys.stdin:
        try:
            answer = client.handle(json.loads(line))
        except tango.DevFailed as exc:
            answer = {"error": str(exc.args[0].reason), "desc": str(exc.args[0].desc)}
        print(json.dumps(answer), flush=True)


if __name__ == "__main__":
    main()
