"""``tango-aio sim``: the emulator served on TCP or a pty, and the ``sim://`` URL built from
its options."""

from __future__ import annotations

import argparse
import errno

from .._argtypes import (
    UsageError,
)

# -- sim --------------------------------------------------------------------------------


async def _sim(args: argparse.Namespace) -> int:
    """Serve an emulated controller on a pty or a TCP port until interrupted."""
    from ..sim.inprocess import configs_from_url, speed_from_url
    from ..sim.model import ControllerModel
    from ..sim.serve import serve_tcp
    from ..sim.wire import Emit

    address = _tcp_address(args.tcp) if args.tcp else None
    if args.per_connection and address is None:
        raise UsageError("--per-connection needs --tcp (a pty serves one controller)")
    url = _sim_url(args)
    sim_config, wire_config = configs_from_url(url)
    speed = speed_from_url(url)

    def factory(emit: Emit) -> ControllerModel:
        return ControllerModel(emit, sim_config)

    factory(lambda data: None)  # a bad --state file: one error now, not one per connection
    if address is not None:
        try:
            server = await serve_tcp(factory, host=address[0], port=address[1],
                                     config=wire_config, speed=speed,
                                     shared=not args.per_connection)
        except OSError as exc:
            raise OSError(_bind_failure(address, exc)) from exc
        host = f"[{server.host}]" if ":" in server.host else server.host
        print(f"socket://{host}:{server.port}", flush=True)
    else:
        _check_pty_platform()
        from ..sim.ptyserve import serve_pty

        server = await serve_pty(factory, config=wire_config,  # type: ignore[assignment]
                                 speed=speed)
        print(server.path, flush=True)  # type: ignore[attr-defined]
    async with server:
        await server.wait_closed()
    return 0


def _bind_failure(address: tuple[str, int], exc: OSError) -> str:
    """Why ``sim --tcp`` could not listen, in words, with the next step."""
    host, port = address
    if exc.errno == errno.EADDRINUSE:
        return (f"port {port} on {host} is already in use (another tango-aio sim?): choose "
                f"another, or --tcp {host}:0 for any free port")
    if exc.errno == errno.EADDRNOTAVAIL:
        return f"{host} is not an address of this machine: use 127.0.0.1 or one of its own"
    if exc.errno in (errno.EACCES, errno.EPERM):
        return f"this user may not listen on port {port}: choose a port above 1023"
    reason = exc.strerror or str(exc)
    return f"cannot listen on {host}:{port}: {reason}"


#: What ``tango-aio sim --pty`` says on Windows (one line).
PTY_NEEDS_POSIX = ("the pty emulator needs a POSIX system (Linux, macOS); on Windows serve "
                   "over TCP: tango-aio sim --tcp 127.0.0.1:4001, then connect to "
                   "socket://127.0.0.1:4001 (or bridge it to a com0com port pair)")


def _check_pty_platform() -> None:
    """Raise a one-line error where there are no ptys (Windows)."""
    from .._platform import WINDOWS

    if WINDOWS:
        raise ValueError(PTY_NEEDS_POSIX)


def _tcp_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT`` (host 127.0.0.1) or ``[IPv6]:PORT`` as (host,
    port); a usage error with the reason for anything else."""
    host, _, port_text = text.rpartition(":")
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host:
        raise UsageError(f"--tcp {text!r}: write an IPv6 address in brackets, e.g. "
                          f"[::1]:4001")
    if not port_text.isdigit() or not 0 <= int(port_text) <= 65535:
        raise UsageError(f"--tcp {text!r}: expected [HOST:]PORT, the port a number 0-65535 "
                          f"(0: any free one), e.g. 4001 or 127.0.0.1:4001")
    return host or "127.0.0.1", int(port_text)


def _sim_url(args: argparse.Namespace) -> str:
    """The ``sim://`` URL of the sim command's options (checked by its parser)."""
    from urllib.parse import urlencode

    from ..sim.profiles import Firmware

    switches = dict(_switch(text) for text in args.switch)
    fingerprint = getattr(args, "fingerprint", None)
    try:
        if fingerprint is not None:
            if args.profile is not None:
                raise ValueError("--fingerprint and --profile exclude each other")
            # A probe's fingerprint: the unit's switch values (unknown names or values)
            Firmware.from_fingerprint(fingerprint).with_(**switches)
            base: dict[str, object] = {"fingerprint": fingerprint}
        else:
            profile = args.profile or "manual"
            Firmware.from_options(profile, **switches)  # unknown names or values
            base = {"profile": profile}
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    query: dict[str, object] = {
        "axes": args.axes, "baud": args.baud, "latency": args.latency,
        "processing": args.processing, "speed": _speed(args.speed), **base, **switches}
    if args.state:
        query["state"] = args.state
    return "sim://?" + urlencode(query)


def _speed(text: str) -> float:
    from ..sim.clock import check_speed

    try:
        return check_speed(float(text))
    except ValueError:
        raise UsageError(f"--speed {text!r}: expected a finite number > 0, e.g. 20") from None


def _switch(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name.strip() or not value.strip():
        raise UsageError(f"--switch {text!r}: expected NAME=VALUE, e.g. echo=after")
    return name.strip(), value.strip()
