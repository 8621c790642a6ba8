"""``tango-aio probe``: the command line."""

from __future__ import annotations

import argparse
import asyncio
import sys
from pathlib import Path
from typing import Any

from .._argtypes import count_type, seconds_type, url_type, writable_path
from ..errors import ProbeError
from ._decide import (
    REPORT_TO,
)
from ._probe import ProbeOptions, probe, write_fingerprint

# ---------------------------------------------------------------------------------------
# The command


def add_probe_command(commands: Any) -> None:
    """Add ``tango-aio probe`` to the CLI's subcommands.

    Parameters
    ----------
    commands
        The CLI's subparsers (``argparse``'s ``add_subparsers()``).
    """
    parser = commands.add_parser(
        "probe", help="learn what a controller's firmware does, write a fingerprint",
        description="Learn from the wire what this controller does where the manual is "
                    "silent, and write a fingerprint (JSON) to send to the project. "
                    "Without --moves nothing moves: it reads, and sets back what it "
                    "changed (the autostatus mode, extmode for one read).")
    parser.add_argument("url", type=url_type,
                        help="controller URL, e.g. /dev/ttyUSB0 or sim://")
    parser.add_argument("-o", "--output", default="tango-fingerprint.json", metavar="FILE",
                        type=writable_path,
                        help="fingerprint file (default tango-fingerprint.json)")
    parser.add_argument("--trace", metavar="FILE", type=writable_path,
                        help="also write the whole wire trace, with timestamps")
    parser.add_argument("--moves", action="store_true",
                        help="also make small moves of X inside its limits (asks first)")
    parser.add_argument("--save", action="store_true",
                        help="also send !save once (stores the present settings as the "
                             "controller's power-on settings)")
    parser.add_argument("--yes", action="store_true",
                        help="do not ask before --moves or --save")
    parser.add_argument("--baudrate", type=count_type, default=57600, help="serial baud rate")
    parser.add_argument("--settle", type=seconds_type, default=0.3,
                        help="seconds of silence that end an exchange (default 0.3)")
    parser.add_argument("--move-time", type=seconds_type, default=0.3,
                        help="about how long each test move takes, s (default 0.3)")
    parser.set_defaults(run=_probe_command)


def _confirm(args: argparse.Namespace) -> bool:
    what = []
    if args.moves:
        what.append("moves axis X by small distances inside its limits and back")
    if args.save:
        what.append("sends !save (the present settings become the power-on settings)")
    print(f"The probe {' and '.join(what)} on the controller at {args.url}.",
          file=sys.stderr)
    if not sys.stdin.isatty():
        raise ValueError("confirm with --yes (stdin is not a terminal to ask)")
    try:
        answer = input("Continue? [y/N] ")
    except EOFError:
        answer = ""
    return answer.strip().lower() in ("y", "yes")


async def _probe_command(args: argparse.Namespace) -> int:
    """``tango-aio probe URL``: writes the fingerprint (0, also when it recorded unknown
    behaviour, which it asks to send), or fails with the error (1)."""
    asks = (args.moves or args.save) and not args.yes and \
        not args.url.lower().startswith("sim://")
    if asks and not await asyncio.to_thread(_confirm, args):
        print("probe cancelled: nothing was sent", file=sys.stderr)
        return 1
    options = ProbeOptions(moves=args.moves, save=args.save, settle=args.settle,
                           move_time=args.move_time, baudrate=args.baudrate)
    try:
        result = await probe(args.url, options)
    except ProbeError as exc:
        if args.trace and exc.trace:
            await asyncio.to_thread(Path(args.trace).write_text, exc.trace, "utf-8")
            print(f"the wire trace so far is in {args.trace}: please send it with the "
                  f"error to {REPORT_TO}", file=sys.stderr)
        raise
    path = await asyncio.to_thread(write_fingerprint, result, args.output)
    if args.trace:
        await asyncio.to_thread(Path(args.trace).write_text, result.trace, "utf-8")
    ident = result.identity
    print(f"{ident.get('model', '?')} firmware {ident.get('firmware', '?')}, "
          f"{result.axes} axes")
    for name, obs in result.observations.items():
        shown = obs.value if obs.value is not None else (
            "UNKNOWN" if obs.unknown else "-")
        print(f"  {name:20} {shown:12} {obs.note}")
    print(f"fingerprint written to {path}" +
          (f", wire trace to {args.trace}" if args.trace else ""))
    if result.unknown:
        print(f"This controller does something no switch describes "
              f"({', '.join(result.unknown)}): the driver may not work with it yet. "
              f"Please send {path}{' and ' + args.trace if args.trace else ''} to "
              f"{REPORT_TO}.")
        return 0
    print(f"Please send {path}{' and ' + args.trace if args.trace else ''} to {REPORT_TO}: "
          f"every unit's fingerprint helps.")
    return 0
